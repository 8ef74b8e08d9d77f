"""Behavior-tree ticking cost: ticks/s of N patrol trees on a real simulator backend.

Builds a generated warehouse for ``--trees`` robots (``fleet.warehouse.generate_warehouse``
+ ``fleet.config.load_config(path, robots=N)``), one :class:`sim.simulator.Simulator` with
every robot, and one :func:`nodes.trees.patrol_tree` per robot, each on its own blackboard
namespace (``/robot<k>``) with a patrol route, a task id and a charger written on it (routes
are the config's routes, round-robin, each robot's copy rotated so robots spread along it).

The loop is the runner's: step the simulator for ``1 / hz`` simulated seconds, then tick every
tree once with ``root.tick_once()``. Only the ``tick_once()`` calls are timed (the tick
timing includes what the leaves do on the backend: sending goals, which plans a path in the
simulator, and reading goal states); simulator stepping is timed separately. The first tick
round (every robot sends its first goal, so 1000 path plans) is reported on its own and left
out of the steady-state figure.

Prints ticks/s and µs per tick, the share of one core that ``--trees`` robots at ``--hz``
cost, the simulator's step cost for comparison, and (``--profile``) the top functions of a
cProfile of the ticking.

    python bench/bench_bt.py --trees 1000 --seconds 10
    python bench/bench_bt.py --trees 200 --seconds 5 --profile
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from typing import Any

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.warehouse import generate_warehouse
from nodes.blackboard import clear_robot_blackboard, robot_blackboard
from nodes.trees import patrol_tree
from sim.simulator import Simulator


@dataclass(frozen=True)
class BtBenchResult:
    """One run. ``ticks_per_s`` and ``us_per_tick`` are steady state (first round excluded);
    ``core_fraction`` = ``trees * hz * us_per_tick / 1e6`` (1.0 = one core busy)."""

    trees: int
    hz: float
    sim_seconds: float
    rounds: int
    first_round_ms: float
    tick_wall_s: float
    ticks_per_s: float
    us_per_tick: float
    core_fraction: float
    sim_step_s: float
    sim_step_ms: float
    sim_core_fraction: float
    statuses: dict[str, int]
    laps: int


def build(trees: int, workdir: str) -> tuple[Simulator, list[Any], list[str]]:
    """The simulator, the tree roots and the namespaces of ``trees`` patrol robots."""
    path = generate_warehouse(workdir, "bench", trees)
    config = load_config(path, robots=trees)
    clock = SimClock()
    sim = Simulator(config.grid, config.sim, clock)
    routes = [config.route_poses(r) for r in config.routes]
    chargers = [c.pose for c in config.chargers]
    roots: list[Any] = []
    names: list[str] = []
    for k, spec in enumerate(config.robots):
        sim.add_robot(spec)
        ns = spec.namespace
        clear_robot_blackboard(ns)
        bb = robot_blackboard(ns, name=f"bench{ns}", keys=("route", "task_id", "charger"))
        route = routes[k % len(routes)]
        shift = (k // len(routes)) % len(route)
        bb.route = route[shift:] + route[:shift]
        bb.task_id = f"p-{k + 1:04d}"
        bb.charger = chargers[k % len(chargers)]
        roots.append(patrol_tree(ns, sim.backend(ns), clock, config.sim.battery))
        names.append(ns)
    return sim, roots, names


def run(trees: int, hz: float, seconds: float, profile: bool = False) -> tuple[BtBenchResult, str]:
    """Run the benchmark; returns the result and the profile text (empty without ``profile``)."""
    with tempfile.TemporaryDirectory(prefix="bench_bt_") as tmp:
        sim, roots, names = build(trees, tmp)
    steps_per_tick = max(1, round(1.0 / hz / sim.params.step_s))
    rounds = max(2, round(seconds * hz))
    prof = cProfile.Profile() if profile else None
    perf = time.perf_counter
    tick_wall = 0.0
    step_wall = 0.0
    steps = 0
    first_round = 0.0
    for r in range(rounds):
        t0 = perf()
        for _ in range(steps_per_tick):
            sim.step()
        step_wall += perf() - t0
        steps += steps_per_tick
        if prof is not None and r > 0:
            prof.enable()
        t0 = perf()
        for root in roots:
            root.tick_once()
        dt = perf() - t0
        if prof is not None and r > 0:
            prof.disable()
        if r == 0:
            first_round = dt
        else:
            tick_wall += dt
    statuses: dict[str, int] = {}
    for root in roots:
        statuses[root.status.name] = statuses.get(root.status.name, 0) + 1
    from py_trees.blackboard import Blackboard

    laps = sum(int(Blackboard.storage.get(f"{ns}/laps", 0) or 0) for ns in names)
    n_ticks = trees * (rounds - 1)
    us = tick_wall / n_ticks * 1e6
    step_ms = step_wall / steps * 1e3
    res = BtBenchResult(
        trees=trees,
        hz=hz,
        sim_seconds=rounds / hz,
        rounds=rounds,
        first_round_ms=first_round * 1e3,
        tick_wall_s=tick_wall,
        ticks_per_s=n_ticks / tick_wall,
        us_per_tick=us,
        core_fraction=trees * hz * us / 1e6,
        sim_step_s=sim.params.step_s,
        sim_step_ms=step_ms,
        sim_core_fraction=step_ms / 1e3 / sim.params.step_s,
        statuses=statuses,
        laps=laps,
    )
    text = ""
    if prof is not None:
        out = io.StringIO()
        pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(15)
        text = out.getvalue()
    for ns in names:
        clear_robot_blackboard(ns)
    return res, text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Ticks/s of N patrol behavior trees on an in-process simulator backend "
        "(only root.tick_once() is timed; sim stepping is reported separately).",
    )
    ap.add_argument("--trees", type=int, default=1000, help="robots, one patrol tree each (default 1000)")
    ap.add_argument(
        "--seconds", type=float, default=10.0, help="simulated seconds to run (default 10; rounds = s * hz)"
    )
    ap.add_argument("--hz", type=float, default=10.0, help="tick rate per tree, simulated Hz (default 10)")
    ap.add_argument("--profile", action="store_true", help="cProfile the ticking and print the top 15")
    ap.add_argument("--json", action="store_true", help="also print the result as one JSON line")
    a = ap.parse_args(argv)
    if a.trees < 1 or a.seconds <= 0 or a.hz <= 0:
        ap.error("--trees, --seconds and --hz must be positive")
    t0 = time.perf_counter()
    res, prof = run(a.trees, a.hz, a.seconds, a.profile)
    print(
        f"bench_bt: {res.trees} patrol trees x {res.rounds} rounds ({res.sim_seconds:g} sim s at {res.hz:g} Hz)\n"
        f"  first round (every robot sends its first goal): {res.first_round_ms:.1f} ms\n"
        f"  steady state: {res.ticks_per_s:,.0f} ticks/s, {res.us_per_tick:.1f} us/tick\n"
        f"  {res.trees} robots at {res.hz:g} Hz cost {res.core_fraction:.2f} of one core for ticking "
        f"({res.core_fraction * 10:.1f} cores at 10x real time)\n"
        f"  sim step ({res.trees} robots): {res.sim_step_ms:.2f} ms per {res.sim_step_s:g} s step = "
        f"{res.sim_core_fraction:.2f} of one core at real time ({res.sim_core_fraction * 10:.1f} at 10x)\n"
        f"  tree statuses at the end: {res.statuses}; laps done: {res.laps}\n"
        f"  total wall time {time.perf_counter() - t0:.1f} s"
    )
    if prof:
        print(prof)
    if a.json:
        print(json.dumps(asdict(res)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
