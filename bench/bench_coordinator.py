"""Coordinator cost: assigning N patrols to N robots, steady-state cycles, one dead robot.

Runs the pure decision logic of :mod:`fleet.coordination.state` (:class:`CoordinatorState`, no bus)
on a generated warehouse for ``--robots`` robots. The patrols are the config's routes; when
there are fewer than ``--routes``, more are synthesized deterministically (``random.Random
(--seed)`` picks 3-5 roadmap nodes, the loop through them along shortest paths is the lap).

Measured (wall time, ``time.perf_counter``; fleet time is simulated and advanced by hand):

1. **initial assignment**: every robot has reported ``idle`` at its start pose; one
   ``step()`` matches ``min(routes, robots)`` patrols (cost matrix + greedy matching);
2. **steady state**: ``--cycles`` cycles at ``--hz``; per cycle every robot's status is fed
   (``observe``: mode ``patrol``, its task id, a pose moving along its lap) and ``step()`` runs;
   ms per cycle is reported for both parts;
3. **one dead robot**: ``--spares`` extra robots idle at their start poses (default 2);
   a patrolling robot's liveliness token drops (``robot_left``) and the next ``step()`` gives
   its route to a spare: the reassignment latency is one cycle (``1/hz`` s of fleet time at
   most) plus that cycle's wall time. The silent-robot path (no status for
   ``status_timeout_s``) is measured too, in fleet time.

    python bench/bench_coordinator.py --routes 1000 --robots 1000
    python bench/bench_coordinator.py --routes 200 --robots 200 --cycles 20
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import time
from dataclasses import asdict, dataclass

from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.coordination.state import CoordinatorState
from fleet.coordination.tasks import PatrolRoute, patrol_routes
from fleet.coordination.views import CoordinatorParams, Observation
from fleet.roadmap.graph import Roadmap
from fleet.types import Mode, Pose2D
from fleet.warehouse import generate_warehouse


@dataclass(frozen=True)
class CoordBenchResult:
    """One run; times are wall milliseconds."""

    robots: int
    spares: int
    routes: int
    synthesized_routes: int
    roadmap_nodes: int
    initial_assign_ms: float
    initial_orders: int
    cycles: int
    observe_ms_per_cycle: float
    step_ms_per_cycle: float
    cycle_ms: float
    steady_orders: int
    dead_cycle_ms: float
    dead_reassigned_to: str | None
    dead_latency_fleet_s: float
    silent_latency_fleet_s: float
    line_robots: int
    line_first_step_ms: float
    line_next_step_ms: float


def synth_routes(config: FleetConfig, n: int, seed: int) -> tuple[list[PatrolRoute], int]:
    """The config's patrol routes, plus synthesized ones up to ``n`` (deterministic)."""
    routes = patrol_routes(config)[:n]
    rm = config.roadmap
    nodes = rm.nodes
    rng = random.Random(seed)
    made = 0
    while len(routes) < n:
        wps = rng.sample(nodes, rng.randint(3, 5))
        dense = rm.expand_route(wps, closed=True)
        if len(dense) < 2:
            continue
        routes.append(PatrolRoute(f"synth_{made:04d}", rm.poses_for(dense, closed=True), tuple(dense)))
        made += 1
    return routes, made


def run_line(n: int) -> tuple[float, float]:
    """Wall ms of the first ``step()`` (``n`` idle robots, ``n`` one-edge routes on a line) and
    of the next one; checks that every robot got a route."""
    nodes = {f"n{i}": [float(i), 0.0] for i in range(n + 1)}
    edges = [[f"n{i}", f"n{i + 1}"] for i in range(n)]
    rm = Roadmap.from_config_dict({"nodes": nodes, "edges": edges})
    routes = [
        PatrolRoute(f"r{i}", rm.poses_for([f"n{i}", f"n{i + 1}"]), (f"n{i}", f"n{i + 1}")) for i in range(n)
    ]
    state = CoordinatorState(routes, [Pose2D(0, 0)], rm)
    for i in range(n):
        state.observe(f"robot{i}", 0.0, Observation(t=0.0, pose=Pose2D(float(n - i) - 0.2, 0.0)))
    t0 = time.perf_counter()
    orders = state.step(0.0)
    first = (time.perf_counter() - t0) * 1e3
    if len(orders) != n:
        raise RuntimeError(f"line: {len(orders)} orders for {n} robots")
    t0 = time.perf_counter()
    state.step(0.1)
    return first, (time.perf_counter() - t0) * 1e3


def run(
    n_routes: int, n_robots: int, spares: int, cycles: int, hz: float, seed: int, line: int = 0
) -> CoordBenchResult:
    total = n_robots + spares
    with tempfile.TemporaryDirectory(prefix="bench_coord_") as tmp:
        config = load_config(generate_warehouse(tmp, "bench", total), robots=total)
    routes, made = synth_routes(config, n_routes, seed)
    params = CoordinatorParams(
        stuck_reassign_s=config.coordinator.stuck_reassign_s,
        status_timeout_s=config.coordinator.status_timeout_s,
        battery_low=config.sim.battery.low,
    )
    state = CoordinatorState(routes, [c.pose for c in config.chargers], config.roadmap, params)
    specs = config.robots
    workers = [s.name for s in specs[:n_robots]]
    spare_names = [s.name for s in specs[n_robots:]]
    start = {s.name: s.start for s in specs}
    perf = time.perf_counter
    dt = 1.0 / hz

    # 1. initial assignment (spares report a moment later so that they stay idle)
    now = 0.0
    for r in workers:
        state.observe(r, now, Observation(t=now, pose=start[r], mode=Mode.IDLE))
    t0 = perf()
    orders = state.step(now)
    initial_ms = (perf() - t0) * 1e3
    initial_orders = len(orders)
    for r in spare_names:
        state.observe(r, now, Observation(t=now, pose=start[r], mode=Mode.IDLE))

    # 2. steady state: every robot reports each cycle, driving along its lap
    def feed(now: float, k: int) -> None:
        for name, v in state.robots.items():
            if not v.alive:
                continue
            a = v.assignment
            if a is None:
                state.observe(name, now, Observation(t=now, pose=start[name], mode=Mode.IDLE))
                continue
            p = a.poses[k % len(a.poses)]
            state.observe(
                name,
                now,
                Observation(
                    t=now, pose=Pose2D(p.x, p.y, p.theta), mode=Mode.PATROL, task_id=a.task_id, laps=0
                ),
            )

    obs_wall = step_wall = 0.0
    steady_orders = 0
    for k in range(cycles):
        now += dt
        t0 = perf()
        feed(now, k)
        t1 = perf()
        steady_orders += len(state.step(now))
        t2 = perf()
        obs_wall += t1 - t0
        step_wall += t2 - t1

    # 3. one dead robot (liveliness token dropped), reassigned to a spare
    held = [(r, a.name) for r in workers if (a := state.robots[r].assignment) is not None]
    dead_ms, to_robot, dead_latency = float("nan"), None, float("nan")
    if held:
        victim, route = held[0]
        t_dead = now
        state.robot_left(victim, t_dead)
        now += dt
        feed(now, cycles)
        t0 = perf()
        state.step(now)
        dead_ms = (perf() - t0) * 1e3
        holder = state.holder.get(route)
        to_robot = holder
        dead_latency = now - t_dead if holder is not None else float("nan")

    # 4. a silent robot (no status any more): reassigned after status_timeout_s
    silent_latency = float("nan")
    busy = [
        (r, a.name)
        for r in workers
        if state.robots[r].alive and (a := state.robots[r].assignment) is not None
    ]
    idle_alive = [r for r, v in state.robots.items() if v.alive and v.assignment is None]
    if busy and idle_alive:
        victim2, route2 = busy[0]
        t_last = now
        for k in range(int((params.status_timeout_s + 2.0) * hz)):
            now += dt
            state.robots[victim2].last_seen = t_last  # never reports again
            for name, v in state.robots.items():
                if name == victim2 or not v.alive:
                    continue
                a = v.assignment
                pose = start[name] if a is None else a.poses[k % len(a.poses)]
                mode = Mode.IDLE if a is None else Mode.PATROL
                state.observe(
                    name,
                    now,
                    Observation(t=now, pose=pose, mode=mode, task_id=None if a is None else a.task_id),
                )
            state.step(now)
            if state.holder.get(route2) not in (None, victim2):
                silent_latency = now - t_last
                break

    line_first, line_next = run_line(line) if line > 0 else (float("nan"), float("nan"))
    return CoordBenchResult(
        robots=n_robots,
        spares=spares,
        routes=len(routes),
        synthesized_routes=made,
        roadmap_nodes=len(config.roadmap),
        initial_assign_ms=initial_ms,
        initial_orders=initial_orders,
        cycles=cycles,
        observe_ms_per_cycle=obs_wall / max(1, cycles) * 1e3,
        step_ms_per_cycle=step_wall / max(1, cycles) * 1e3,
        cycle_ms=(obs_wall + step_wall) / max(1, cycles) * 1e3,
        steady_orders=steady_orders,
        dead_cycle_ms=dead_ms,
        dead_reassigned_to=to_robot,
        dead_latency_fleet_s=dead_latency,
        silent_latency_fleet_s=silent_latency,
        line_robots=line,
        line_first_step_ms=line_first,
        line_next_step_ms=line_next,
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Wall time of the coordinator's pure assignment logic (fleet.coordination.state."
        "CoordinatorState): initial assignment, steady-state cycles, reassignment of a dead robot.",
    )
    ap.add_argument(
        "--routes", type=int, default=1000, help="patrol routes (synthesized beyond the config's)"
    )
    ap.add_argument("--robots", type=int, default=1000, help="patrolling robots (default 1000)")
    ap.add_argument(
        "--spares", type=int, default=2, help="extra idle robots that take over routes (default 2)"
    )
    ap.add_argument("--cycles", type=int, default=50, help="steady-state cycles to time (default 50)")
    ap.add_argument("--hz", type=float, default=10.0, help="coordinator cycles per fleet second (default 10)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the synthesized routes (default 1)")
    ap.add_argument(
        "--line",
        type=int,
        default=1000,
        help="robots and routes of the line scenario (default 1000; 0 skips)",
    )
    ap.add_argument("--json", action="store_true", help="also print the result as one JSON line")
    a = ap.parse_args(argv)
    if a.routes < 1 or a.robots < 1 or a.spares < 0 or a.cycles < 1 or a.hz <= 0 or a.line < 0:
        ap.error("--routes, --robots, --cycles, --hz must be positive and --spares, --line >= 0")
    t0 = time.perf_counter()
    r = run(a.routes, a.robots, a.spares, a.cycles, a.hz, a.seed, a.line)
    print(
        f"bench_coordinator: {r.routes} routes ({r.synthesized_routes} synthesized) on a "
        f"{r.roadmap_nodes}-node roadmap, {r.robots} robots + {r.spares} spare(s)\n"
        f"  initial assignment: {r.initial_assign_ms:.1f} ms ({r.initial_orders} orders)\n"
        f"  steady state ({r.cycles} cycles, every robot reports each cycle): {r.cycle_ms:.2f} ms/cycle "
        f"= {r.observe_ms_per_cycle:.2f} ms observe + {r.step_ms_per_cycle:.2f} ms step "
        f"({r.steady_orders} orders); at {a.hz:g} Hz that is {r.cycle_ms * a.hz / 1e3:.2f} of one core\n"
        f"  dead robot (token dropped): route reassigned to {r.dead_reassigned_to} in the next cycle "
        f"({r.dead_latency_fleet_s:.2f} s fleet time, cycle wall {r.dead_cycle_ms:.2f} ms)\n"
        f"  silent robot: route reassigned {r.silent_latency_fleet_s:.2f} s (fleet time) after its last status\n"
        + (
            f"  line of {r.line_robots} robots and routes: first step {r.line_first_step_ms:.1f} ms "
            f"(every robot matched), next step {r.line_next_step_ms:.2f} ms\n"
            if r.line_robots
            else ""
        )
        + f"  total wall time {time.perf_counter() - t0:.1f} s"
    )
    if a.json:
        print(json.dumps(asdict(r)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
