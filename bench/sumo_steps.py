"""SUMO side of the "simulator vs SUMO robot-steps/s" benchmark.

Runs ``N`` robots as SUMO vehicles through :class:`sim.sumo.world.SumoWorld` (the same
backend protocol the behavior trees use) for ``K`` steps and reports robot-steps per wall
second (``N * K / elapsed``). Every robot patrols: it gets a NavigateThroughPoses through
``poses_per_goal`` random roadmap nodes (or, with ``routes``, its patrol route as the
simulator's side does) and a new one whenever its goal ends; goals are polled
at ``poll_hz`` of simulated time, like agents ticking their trees (every goal's status in one
call by default, as the simulator's side of ``bench/sim_vs_sumo.py`` does). As for patrol routes, the
goal's poses are every node of the shortest roadmap paths between the random nodes, each facing
the next node. Network building and SUMO
start-up, inserting the vehicles and routing every robot's first goal are excluded from the
timing (reported as ``setup_wall_s``); later goals are routed inside the timed loop.

The default network is a generated grid roadmap (``--grid 40x40 --spacing 20``, as in
``/work/shared/NOTES.md``); ``--config`` uses a fleet config's warehouse roadmap, robot model
and start poses instead (``fleet.config.load_config(path, robots=N)``).

Command line (prints one line per run and a JSON record with ``--json``)::

    python bench/sumo_steps.py --robots 200 --steps 1000
    python bench/sumo_steps.py --robots 1000 --steps 300 --grid 40x40 --spacing 20
    python bench/sumo_steps.py --robots 50 --steps 2000 --config configs/warehouse_patrol.yaml
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import networkx as nx

from fleet.clock import SimClock
from fleet.robots import RobotSpec, SimParams
from fleet.types import GoalStatus, NavigateThroughPoses, Pose2D


@dataclass(frozen=True)
class SumoBenchResult:
    """One benchmark run. ``robot_steps_per_s = robots * steps / step_wall_s``."""

    robots: int
    steps: int
    step_s: float
    network: str
    junctions: int
    lanes: int
    setup_wall_s: float
    step_wall_s: float
    robot_steps_per_s: float
    real_time_factor: float
    goals_succeeded: int
    goals_failed: int
    collisions: int
    teleports: int


def grid_starts(graph: nx.Graph, n: int, rng: random.Random) -> list[Pose2D]:
    """``n`` start poses spread over the roadmap's edges (mid-edge, alternating directions,
    several per edge 3 m apart when there are more robots than edges)."""
    edges = list(graph.edges)
    rng.shuffle(edges)
    starts: list[Pose2D] = []
    slot = 0
    while len(starts) < n:
        for u, v in edges:
            if len(starts) >= n:
                break
            (x1, y1), (x2, y2) = graph.nodes[u]["pos"], graph.nodes[v]["pos"]
            length = math.dist((x1, y1), (x2, y2))
            if slot % 2:
                x1, y1, x2, y2 = x2, y2, x1, y1
            f = 0.5 + (slot // 2) * 3.0 / max(length, 1e-9)
            if f >= 0.85:
                continue
            theta = math.atan2(y2 - y1, x2 - x1)
            # 0.45 m to the right of the center line: on the lane driving that way
            ox, oy = math.sin(theta) * 0.45, -math.cos(theta) * 0.45
            starts.append(Pose2D(x1 + f * (x2 - x1) + ox, y1 + f * (y2 - y1) + oy, theta))
        slot += 1
        if slot > 64:
            raise ValueError(f"cannot place {n} robots on a roadmap with {len(edges)} edges")
    return starts


def patrol_poses(graph: nx.Graph, waypoints: list[Any]) -> tuple[Pose2D, ...]:
    """Poses at every node of the shortest roadmap paths through ``waypoints``, each facing
    the next node (as ``fleet.roadmap.Roadmap.poses_for`` gives patrol routes)."""
    dense: list[Any] = [waypoints[0]]
    for a, b in zip(waypoints, waypoints[1:], strict=False):
        dense += nx.shortest_path(graph, a, b, weight="length")[1:]
    pts = [tuple(map(float, graph.nodes[n]["pos"])) for n in dense]
    poses = []
    for i, (x, y) in enumerate(pts):
        if i + 1 < len(pts):
            theta = math.atan2(pts[i + 1][1] - y, pts[i + 1][0] - x)
        elif i > 0:
            theta = math.atan2(y - pts[i - 1][1], x - pts[i - 1][0])
        else:
            theta = 0.0
        poses.append(Pose2D(x, y, theta))
    return tuple(poses)


def run_sumo_steps(
    n_robots: int,
    steps: int,
    *,
    roadmap: Any = None,
    robots: list[RobotSpec] | None = None,
    params: SimParams | None = None,
    grid: tuple[int, int] = (40, 40),
    spacing: float = 20.0,
    poses_per_goal: int = 3,
    poll_hz: float = 10.0,
    internal_links: bool = False,
    seed: int = 1,
    cache_dir: str | Path | None = None,
    progress: bool = False,
    batch: bool = True,
    routes: list[tuple[Pose2D, ...]] | None = None,
) -> SumoBenchResult:
    """Run the benchmark once and return its figures (see the module docstring).

    ``roadmap`` (a graph or ``fleet.roadmap.Roadmap``) defaults to a ``grid`` of nodes
    ``spacing`` m apart; ``robots`` default to :func:`grid_starts`; ``params`` default to
    ``SimParams(step_s=0.1, seed=seed)``. ``batch``: poll every goal's status in one call
    (``sim.goals.GoalBook.status_codes`` of the world's goal book); else one ``goal_state``
    snapshot per goal. ``routes``: robot ``i`` patrols ``routes[i mod len(routes)]`` (a
    NavigateThroughPoses of its poses, as the simulator's side of ``bench/sim_vs_sumo.py``)
    instead of random roadmap nodes.
    """
    from sim.goals import STATUS_CODES, TERMINAL
    from sim.sumo.net import as_graph, grid_roadmap
    from sim.sumo.world import SumoWorld

    rng = random.Random(seed)
    params = params or replace(SimParams(), step_s=0.1, seed=seed)
    graph = as_graph(roadmap) if roadmap is not None else grid_roadmap(grid[0], grid[1], spacing)
    if robots is None:
        robots = [
            RobotSpec(f"robot{i + 1}", f"/robot{i + 1}", p)
            for i, p in enumerate(grid_starts(graph, n_robots, rng))
        ]
    robots = robots[:n_robots]
    nodes = list(graph.nodes)
    t0 = time.perf_counter()
    world = SumoWorld(graph, robots, params, SimClock(), cache_dir=cache_dir, internal_links=internal_links)
    try:
        backends = [world.backend(r.namespace) for r in robots]
        goals: list[str | None] = [None] * len(backends)
        counts = {"ok": 0, "failed": 0}

        def dispatch() -> None:
            if batch and None not in goals:
                # one call for every goal: the world's goal book as status codes
                codes = world._goals.status_codes(goals)  # type: ignore[arg-type]
                todo = TERMINAL[codes].nonzero()[0].tolist()
            else:
                codes, todo = None, range(len(backends))
            for i in todo:
                b, gid = backends[i], goals[i]
                if gid is not None:
                    status = STATUS_CODES[codes[i]] if codes is not None else b.goal_state(gid).status
                    if not status.terminal:
                        continue
                    counts["ok" if status is GoalStatus.SUCCEEDED else "failed"] += 1
                if routes:
                    poses = routes[i % len(routes)]
                else:
                    poses = patrol_poses(graph, rng.sample(nodes, poses_per_goal))
                goals[i] = b.send_goal(NavigateThroughPoses(poses))

        # warm-up, not timed: insert the vehicles and route every robot's first goal
        world.step()
        dispatch()
        world.step()
        setup = time.perf_counter() - t0
        poll_every = max(1, round(1.0 / (poll_hz * params.step_s)))
        t1 = time.perf_counter()
        for k in range(steps):
            if k % poll_every == 0:
                dispatch()
            world.step()
            if progress and (k + 1) % max(1, steps // 10) == 0:
                el = time.perf_counter() - t1
                print(
                    f"  step {k + 1}/{steps}: {len(robots) * (k + 1) / el:,.0f} robot-steps/s",
                    file=sys.stderr,
                )
        elapsed = time.perf_counter() - t1
        lanes = len(world.lanes.lanes)
        return SumoBenchResult(
            robots=len(robots),
            steps=steps,
            step_s=params.step_s,
            network=str(world.network.net_path),
            junctions=graph.number_of_nodes(),
            lanes=lanes,
            setup_wall_s=setup,
            step_wall_s=elapsed,
            robot_steps_per_s=len(robots) * steps / elapsed,
            real_time_factor=steps * params.step_s / elapsed,
            goals_succeeded=counts["ok"],
            goals_failed=counts["failed"],
            collisions=world.collisions,
            teleports=world.teleports,
        )
    finally:
        world.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Robot-steps per second of N robots driving on SUMO (libsumo) through the "
        "fleet's SUMO navigation backend.",
        epilog="Example: python bench/sumo_steps.py --robots 1000 --steps 300",
    )
    ap.add_argument("--robots", "-n", type=int, default=200, help="number of robots (default 200)")
    ap.add_argument("--steps", "-k", type=int, default=1000, help="simulation steps to time (default 1000)")
    ap.add_argument("--step-s", type=float, default=0.1, help="SUMO step length in s (default 0.1)")
    ap.add_argument("--grid", default="40x40", help="grid roadmap COLSxROWS (default 40x40)")
    ap.add_argument("--spacing", type=float, default=20.0, help="grid node spacing in m (default 20)")
    ap.add_argument("--config", help="use this fleet config's roadmap, robot model and start poses")
    ap.add_argument(
        "--internal-links",
        action="store_true",
        help="model the lanes inside junctions (slower; queues inside junctions gridlock dense fleets)",
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument("--progress", action="store_true", help="print progress to stderr")
    args = ap.parse_args(argv)
    cols, rows = (int(v) for v in args.grid.lower().split("x"))
    kw: dict[str, Any] = {}
    if args.config:
        from fleet.config.loader import load_config

        cfg = load_config(args.config, robots=args.robots)
        kw = {
            "roadmap": cfg.roadmap,
            "robots": list(cfg.robots),
            "params": replace(cfg.sim, step_s=args.step_s, seed=args.seed),
        }
    res = run_sumo_steps(
        args.robots,
        args.steps,
        grid=(cols, rows),
        spacing=args.spacing,
        internal_links=args.internal_links,
        seed=args.seed,
        progress=args.progress,
        **kw,
    )
    if args.json:
        print(json.dumps(asdict(res)))
    else:
        where = args.config or f"{cols}x{rows} grid, {args.spacing:g} m"
        print(
            f"SUMO: {res.robots} robots x {res.steps} steps of {res.step_s:g} s on {where}: "
            f"{res.robot_steps_per_s:,.0f} robot-steps/s ({res.real_time_factor:.1f}x real time; "
            f"setup {res.setup_wall_s:.1f} s; goals ok {res.goals_succeeded}, failed {res.goals_failed}; "
            f"collisions {res.collisions}, teleports {res.teleports})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
