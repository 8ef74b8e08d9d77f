"""Robot-steps per second of the kinematic simulator (``sim.simulator.Simulator``) on a
generated warehouse.

The world is ``fleet.warehouse.generate_warehouse(tmp, "bench", N)`` loaded with
``fleet.config.load_config(path, robots=N)``: its map, robot model, parameters and start poses.
Robot ``i`` patrols route ``i mod len(routes)``: it gets a NavigateThroughPoses of
``config.route_poses(route)`` and the same goal again whenever its goal ends (succeeded,
aborted or stuck). Goals are polled every ``1 / poll_hz`` simulated seconds, as agents tick
their trees. Generating the world, adding the robots and planning every robot's first goal are
excluded from the timing (``setup_wall_s``); later goals (re-planned patrol laps) are inside
the timed loop. The headline figure is ``N * K / wall seconds of the K timed steps`` including
the goal polling (``goal_state`` of every robot at ``poll_hz``), as in ``bench/sumo_steps.py``;
``step_only_*`` counts the time inside ``Simulator.step()`` alone and ``poll_wall_s`` the time in
the polling rounds (the goals re-sent included). Polling reads every robot's state and goal in
one ``Simulator.query_batch(namespaces, goal_ids)`` call (the navigation contract's batch query,
as the fleet runner's scheduler does: arrays, no snapshot objects); ``--per-goal`` polls with
one ``goal_state`` snapshot per goal instead.

Command line::

    python bench/bench_sim.py --robots 1000 --steps 500
    python bench/bench_sim.py --robots 30 --steps 2000 --json
    python bench/bench_sim.py --robots 1000 --steps 200 --warmup 200 --profile   # cProfile of step()
    python bench/bench_sim.py --robots 1000 --steps 200 --warmup 200 --stages    # stage timers
    python bench/bench_sim.py --scenes    # speed of the unit tests' scenes and the planner
    python bench/bench_sim.py --robots 1000 --query   # ms of one query_batch of every robot
    python bench/bench_sim.py --robots 5000 --steps 200 --cpu-time   # CPU s, not wall s
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from fleet.clock import SimClock
from fleet.types import GoalStatus, NavigateThroughPoses


@dataclass(frozen=True)
class SimBenchResult:
    """One run. ``robot_steps_per_s = robots * steps / step_wall_s``."""

    robots: int
    steps: int
    step_s: float
    map_size_m: tuple[float, float]
    setup_wall_s: float
    step_wall_s: float
    robot_steps_per_s: float
    real_time_factor: float
    step_only_wall_s: float
    step_only_robot_steps_per_s: float
    poll_wall_s: float
    goals_succeeded: int
    goals_failed: int
    collisions: int
    distance_m: float


def load_world(n_robots: int, out_dir: str | Path | None = None) -> Any:
    """Generate the benchmark warehouse for ``n_robots`` and load its config."""
    from fleet.config.loader import load_config
    from fleet.warehouse import generate_warehouse

    out = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="bench_sim_"))
    path = generate_warehouse(out, "bench", n_robots)
    return load_config(path, robots=n_robots)


def run_sim_steps(
    cfg: Any,
    steps: int,
    *,
    step_s: float = 0.05,
    poll_hz: float = 10.0,
    profile: bool = False,
    progress: bool = False,
    warmup: int = 0,
    stages: bool = False,
    batch: bool = True,
) -> SimBenchResult:
    """Run ``steps`` timed steps of every robot of ``cfg`` patrolling (module docstring).
    ``batch``: poll every goal at once with ``Simulator.query_batch``; else one
    ``goal_state`` snapshot per goal."""
    from sim.goals import STATUS_CODES, TERMINAL
    from sim.simulator import Simulator

    t0 = time.perf_counter()
    params = replace(cfg.sim, step_s=step_s)
    sim = Simulator(cfg.grid, params, SimClock())
    for spec in cfg.robots:
        sim.add_robot(spec)
    routes = [cfg.route_poses(r) for r in cfg.routes]
    nss = sim.namespaces
    goals: list[str] = []
    counts = {"ok": 0, "failed": 0}
    for i, ns in enumerate(nss):
        goals.append(sim.send_goal(ns, NavigateThroughPoses(routes[i % len(routes)])))
    setup = time.perf_counter() - t0

    def dispatch_each() -> None:
        for i, ns in enumerate(nss):
            status = sim.goal_state(goals[i]).status
            if status.terminal:
                counts["ok" if status is GoalStatus.SUCCEEDED else "failed"] += 1
                goals[i] = sim.send_goal(ns, NavigateThroughPoses(routes[i % len(routes)]))

    def dispatch_table() -> None:
        # the navigation contract's batch query: every robot's state and goal in one call
        codes = sim.query_batch(nss, goals).goal_status
        for i in TERMINAL[codes].nonzero()[0].tolist():
            counts["ok" if STATUS_CODES[codes[i]] is GoalStatus.SUCCEEDED else "failed"] += 1
            goals[i] = sim.send_goal(nss[i], NavigateThroughPoses(routes[i % len(routes)]))

    dispatch = dispatch_table if batch else dispatch_each

    poll_every = max(1, round(1.0 / (poll_hz * step_s)))
    prof = cProfile.Profile() if profile else None
    for k in range(warmup):
        if k % poll_every == 0:
            dispatch()
        sim.step()
    stage_s: dict[str, float] = {}
    if stages:
        _time_stages(sim, stage_s)
    step_only = 0.0
    poll = 0.0
    t1 = time.perf_counter()
    for k in range(steps):
        if k % poll_every == 0:
            tp = time.perf_counter()
            dispatch()
            poll += time.perf_counter() - tp
        ts = time.perf_counter()
        if prof is not None:
            prof.enable()
        sim.step()
        if prof is not None:
            prof.disable()
        step_only += time.perf_counter() - ts
        if progress and (k + 1) % max(1, steps // 10) == 0:
            el = time.perf_counter() - t1
            print(f"  step {k + 1}/{steps}: {len(nss) * (k + 1) / el:,.0f} robot-steps/s", file=sys.stderr)
    elapsed = time.perf_counter() - t1
    if prof is not None:
        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(20)
    if stages:
        parts = ", ".join(f"{k} {v / steps * 1000:.2f}" for k, v in stage_s.items())
        print(
            "  stage ms/step (nested: follow includes corridor_free or way blocked, detour (which includes pair "
            "blocks and footprint free, or detour blocks); pairs.update includes neighbor_pairs; move includes "
            "footprint free; compiled runs limit_stop_move instead of reactive_stop and move, and avoid instead "
            "of way blocked and detour): "
            f"{parts}",
            file=sys.stderr,
        )
    xmin, xmax, ymin, ymax = cfg.grid.extent
    return SimBenchResult(
        robots=len(nss),
        steps=steps,
        step_s=step_s,
        map_size_m=(round(xmax - xmin, 1), round(ymax - ymin, 1)),
        setup_wall_s=setup,
        step_wall_s=elapsed,
        robot_steps_per_s=len(nss) * steps / elapsed,
        real_time_factor=steps * step_s / elapsed,
        step_only_wall_s=step_only,
        step_only_robot_steps_per_s=len(nss) * steps / step_only,
        poll_wall_s=poll,
        goals_succeeded=counts["ok"],
        goals_failed=counts["failed"],
        collisions=sim.collisions,
        distance_m=sum(sim.robot_state(ns).distance_m for ns in nss),
    )


def _time_stages(sim: Any, stage_s: dict[str, float]) -> None:
    """Wrap the step's stages (``sim.simulator`` internals) with timers adding to ``stage_s``."""
    import sim.spatial as spatial

    def timed(owner: Any, name: str, label: str) -> None:
        inner = getattr(owner, name)

        def wrapper(*a: Any, **kw: Any) -> Any:
            t = time.perf_counter()
            try:
                return inner(*a, **kw)
            finally:
                stage_s[label] = stage_s.get(label, 0.0) + time.perf_counter() - t

        setattr(owner, name, wrapper)

    follower = sim._follower
    avoidance = follower.avoidance
    timed(spatial, "neighbor_pairs", "neighbor_pairs")
    timed(sim._pairs, "update", "pairs.update")
    timed(sim._dispatch, "control", "dispatch.control")
    timed(follower, "follow", "follow")
    timed(avoidance, "corridor_free", "corridor_free")
    timed(avoidance, "detour", "detour")
    timed(avoidance, "_pair_blocks", "pair blocks")
    timed(avoidance.footprints, "free", "footprint free")
    # compiled: the detour's neighbor and static tests in one pass, the follower's corridor test
    timed(avoidance, "_compiled_blocks", "detour blocks")
    timed(follower, "_blocked_compiled", "way blocked")
    # compiled, without dynamic obstacles: the corridor test, the detour search and the turn in one
    timed(follower, "_avoid_compiled", "avoid")
    timed(sim._upkeep, "update", "battery + progress")
    timed(sim._safety, "reactive_stop", "reactive_stop")
    timed(sim._safety, "move", "move")
    # compiled, without dynamic obstacles: the limits, the reactive stop and the move in one
    timed(sim._safety, "limit_stop_move", "limit_stop_move")
    timed(sim._contacts, "count", "contacts")
    timed(sim.costmaps, "sense", "costmaps.sense")


def _room(width_m: float, height_m: float, res: float = 0.1) -> Any:
    """A walled empty room with origin (0, 0)."""
    import numpy as np

    from fleet.maps import OCCUPIED, OccupancyGrid

    cells = np.zeros((int(round(height_m / res)), int(round(width_m / res))), dtype=np.int8)
    cells[0, :] = cells[-1, :] = OCCUPIED
    cells[:, 0] = cells[:, -1] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=res, origin_x=0.0, origin_y=0.0, source="<bench room>")


def _room_rate(n: int, cols: int, warm_s: float, timed_s: float) -> float:
    """Robot-steps/s of ``n`` robots in a 40 x 30 m room, in rows of ``cols`` 1 m apart, each
    driving 15 m (columns) or along x (rows of 5) to its goal; ``warm_s`` untimed seconds first."""
    from fleet.robots import RobotSpec, SimParams
    from fleet.types import NavigateToPose, Pose2D
    from sim.simulator import Simulator

    sim = Simulator(_room(40.0, 30.0), SimParams(), SimClock())
    for i in range(n):
        sim.add_robot(
            RobotSpec(f"r{i}", f"/r{i}", Pose2D(1.0 + (i % cols) * 1.0, 1.0 + (i // cols) * 1.0, 0.0))
        )
    for i, ns in enumerate(sim.namespaces):
        if cols == 5:
            goal = Pose2D(30.0 + (i % 5) * 1.0, 1.0 + (i // 5) * 1.0, 0.0)
        else:
            goal = Pose2D(1.0 + (i % cols) * 1.0, 16.0 + (i // cols) * 1.0, 0.0)
        sim.send_goal(ns, NavigateToPose(goal))
    step = sim.params.step_s
    for _ in range(round(warm_s / step)):
        sim.step()
    k = round(timed_s / step)
    t0 = time.perf_counter()
    for _ in range(k):
        sim.step()
    return n * k / (time.perf_counter() - t0)


def query_cost(cfg: Any, steps: int = 40, calls: int = 50) -> str:
    """Wall ms of one ``Simulator.query_batch`` over every robot and its goal (the rows a
    runner polls) and of ``goal_table`` / ``robot_table``, after ``steps`` steps of patrolling."""
    from sim.simulator import Simulator

    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    for spec in cfg.robots:
        sim.add_robot(spec)
    routes = [cfg.route_poses(r) for r in cfg.routes]
    nss = sim.namespaces
    goals = [sim.send_goal(ns, NavigateThroughPoses(routes[i % len(routes)])) for i, ns in enumerate(nss)]
    for _ in range(steps):
        sim.step()
    out = []
    for name, fn in (
        ("query_batch", lambda: sim.query_batch(nss, goals)),
        ("goal_table", sim.goal_table),
        ("robot_table", sim.robot_table),
    ):
        fn()
        t = time.perf_counter()
        for _ in range(calls):
            fn()
        out.append(f"{name} {(time.perf_counter() - t) / calls * 1000:.3f} ms")
    return f"{len(nss)} robots, one call each: " + ", ".join(out)


def scenes() -> list[str]:
    """The speed figures of the simulator's unit-test scenes (the tests assert behaviour only):
    30 and 400 robots crossing a 40 x 30 m room, and the planner on a 40 x 30 m warehouse."""
    from fleet.maps import OCCUPIED
    from sim.planner import GridPlanner

    lines = [
        f"30 robots crossing a 40 x 30 m room: {_room_rate(30, 5, 0.0, 10.0):,.0f} robot-steps/s",
        f"400 robots crossing a 40 x 30 m room: {_room_rate(400, 38, 1.0, 5.0):,.0f} robot-steps/s",
    ]
    g = _room(40.0, 30.0)
    for k in range(8):  # shelf rows with aisles between them, a long wall across the middle
        x0 = 40 + k * 45
        g.cells[30:270, x0 : x0 + 15] = OCCUPIED
    g.cells[150:152, 40:360] = OCCUPIED
    planner = GridPlanner(g, 0.3)
    pairs = [((2.0, 2.0), (38.0, 28.0)), ((6.0, 10.0), (34.0, 20.0)), ((2.0, 15.0), (38.5, 15.0))]
    took = []
    for start, goal in pairs:
        t0 = time.perf_counter()
        planner.plan(start, goal)
        took.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    planner.plan(*pairs[0])
    cached = time.perf_counter() - t0
    lines.append(
        f"planner on a 40 x 30 m warehouse: {', '.join(f'{t * 1000:.1f}' for t in took)} ms for 3 plans, "
        f"{cached * 1e6:.0f} us for a cached one"
    )
    return lines


def describe(res: SimBenchResult) -> str:
    return (
        f"sim: {res.robots} robots x {res.steps} steps of {res.step_s:g} s on a "
        f"{res.map_size_m[0]:g} x {res.map_size_m[1]:g} m warehouse: {res.robot_steps_per_s:,.0f} robot-steps/s "
        f"({res.step_wall_s / res.steps * 1000:.2f} ms/step, {res.real_time_factor:.1f}x real time; "
        f"Simulator.step() alone {res.step_only_robot_steps_per_s:,.0f} robot-steps/s, "
        f"{res.step_only_wall_s / res.steps * 1000:.2f} ms/step; polling "
        f"{res.poll_wall_s / res.steps * 1000:.2f} ms/step; setup "
        f"{res.setup_wall_s:.1f} s; goals ok {res.goals_succeeded}, failed {res.goals_failed}; "
        f"collisions {res.collisions}; {res.distance_m:,.0f} m driven)"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Robot-steps per second of the kinematic simulator with N robots patrolling "
        "a generated warehouse (fleet.warehouse).",
        epilog="Example: python bench/bench_sim.py --robots 1000 --steps 500",
    )
    ap.add_argument("--robots", "-n", type=int, default=1000, help="number of robots (default 1000)")
    ap.add_argument("--steps", "-k", type=int, default=500, help="steps to time (default 500)")
    ap.add_argument("--step-s", type=float, default=0.05, help="step length in s (default 0.05)")
    ap.add_argument("--poll-hz", type=float, default=10.0, help="goal polling rate, sim Hz (default 10)")
    ap.add_argument(
        "--per-goal",
        action="store_true",
        help="poll with one goal_state snapshot per goal instead of one Simulator.query_batch() call",
    )
    ap.add_argument("--out", help="directory for the generated warehouse (default: a temp dir)")
    ap.add_argument("--warmup", type=int, default=0, help="untimed steps before the timed ones (default 0)")
    ap.add_argument(
        "--profile", action="store_true", help="cProfile Simulator.step() of the timed steps (stderr)"
    )
    ap.add_argument("--stages", action="store_true", help="time the step's stages (stderr)")
    ap.add_argument("--progress", action="store_true", help="print progress to stderr")
    ap.add_argument(
        "--cpu-time",
        action="store_true",
        help="time in this process's CPU seconds instead of wall seconds (on a shared machine wall time is "
        "mostly waiting for a core)",
    )
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument(
        "--query", action="store_true", help="print the cost of one batch read of every robot instead"
    )
    ap.add_argument(
        "--scenes",
        action="store_true",
        help="print the speed of the unit tests' scenes (30 / 400 robots in a room, the planner) instead",
    )
    args = ap.parse_args(argv)
    if args.cpu_time:
        # every timing here reads time.perf_counter at each call
        time.perf_counter = time.process_time
    if args.scenes:
        for line in scenes():
            print(line)
        return 0
    cfg = load_world(args.robots, args.out)
    if args.query:
        print(query_cost(cfg))
        return 0
    res = run_sim_steps(
        cfg,
        args.steps,
        step_s=args.step_s,
        poll_hz=args.poll_hz,
        profile=args.profile,
        progress=args.progress,
        warmup=args.warmup,
        stages=args.stages,
        batch=not args.per_goal,
    )
    print(json.dumps(asdict(res)) if args.json else describe(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
