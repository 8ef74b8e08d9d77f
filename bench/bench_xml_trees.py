"""Trees from BehaviorTree.CPP XML against the Python builders, in one run: the cost to load
a tree per robot, and the cost of ticking N patrol robots built from ``nodes/trees/patrol.xml``
against N built by :func:`nodes.trees.patrol_tree`, on one simulator each (same generated
warehouse, same routes). Also the cost of one navigator goal (``nodes/navigator.py``) with the
project's NavigateToPose tree. Prints the figures and the XML / builder ratios.

    python bench/bench_xml_trees.py --robots 200 --seconds 60
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from py_trees.behaviour import Behaviour  # noqa: E402
from py_trees.blackboard import Blackboard  # noqa: E402

from fleet.clock import SimClock  # noqa: E402
from fleet.config.loader import load_config  # noqa: E402
from fleet.config.model import FleetConfig  # noqa: E402
from fleet.types import GoalStatus, NavigateToPose, Pose2D  # noqa: E402
from fleet.warehouse import generate_warehouse  # noqa: E402
from nodes.blackboard import robot_blackboard  # noqa: E402
from nodes.navigator import BtNavigator  # noqa: E402
from nodes.trees import patrol_tree  # noqa: E402
from nodes.xml_tree import load_tree  # noqa: E402
from sim.simulator import Simulator  # noqa: E402

PATROL_XML = ROOT / "nodes" / "trees" / "patrol.xml"


def _fleet(cfg: FleetConfig, xml: bool) -> tuple[Simulator, list[Behaviour], float]:
    """A simulator with every robot, one tree per robot (XML or builder); the build time (s)."""
    Blackboard.clear()
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    roots: list[Behaviour] = []
    routes = [cfg.route_poses(r) for r in cfg.routes]
    t0 = time.perf_counter()
    for k, spec in enumerate(cfg.robots):
        sim.add_robot(spec)
        b = sim.backend(spec.namespace)
        if xml:
            roots.append(load_tree(PATROL_XML, spec.namespace, b, sim.clock, cfg.sim.battery).root)
        else:
            roots.append(patrol_tree(spec.namespace, b, sim.clock, cfg.sim.battery))
        route = routes[k % len(routes)]
        shift = (k // len(routes)) % len(route)
        bb = robot_blackboard(spec.namespace, name=f"bench{k}", keys=("route", "task_id", "charger"))
        bb.route = route[shift:] + route[:shift]
        bb.task_id = f"t{k}"
        bb.charger = cfg.chargers[k % len(cfg.chargers)].pose
    return sim, roots, time.perf_counter() - t0


def _tick(sim: Simulator, roots: list[Behaviour], seconds: float, hz: float) -> tuple[float, int]:
    """Step ``seconds`` of simulated time, ticking every tree at ``hz``; (tick wall s, ticks)."""
    steps = max(1, round(1.0 / (hz * sim.params.step_s)))
    spent, ticks = 0.0, 0
    for _ in range(int(seconds * hz)):
        for _ in range(steps):
            sim.step()
        t0 = time.perf_counter()
        for r in roots:
            r.tick_once()
        spent += time.perf_counter() - t0
        ticks += len(roots)
    return spent, ticks


def _navigator_goal(cfg: FleetConfig) -> tuple[float, float, int]:
    """(wall s, simulated s, ticks) of one NavigateToPose across the warehouse via the navigator."""
    Blackboard.clear()
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    spec = cfg.robots[0]
    sim.add_robot(spec)
    nav = BtNavigator(sim.backend(spec.namespace), sim.clock, battery=cfg.sim.battery)
    far = max(cfg.roadmap.nodes, key=lambda n: cfg.roadmap.pos(n)[0] + cfg.roadmap.pos(n)[1])
    x, y = cfg.roadmap.pos(far)
    t0 = time.perf_counter()
    gid = nav.send_goal(NavigateToPose(Pose2D(x, y, 0.0)))
    while not nav.goal_state(gid).status.terminal and sim.clock.now() < 600:
        sim.step()
        nav.tick()
    assert nav.goal_state(gid).status is GoalStatus.SUCCEEDED, nav.goal_state(gid).error_msg
    return time.perf_counter() - t0, sim.clock.now(), nav.ticks


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds ticked per variant")
    ap.add_argument("--hz", type=float, default=10.0)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = generate_warehouse(Path(tmp), "bench_xml", args.robots)
        cfg = load_config(path, robots=args.robots)
        res = {}
        for xml in (False, True):
            sim, roots, build_s = _fleet(cfg, xml)
            tick_s, ticks = _tick(sim, roots, args.seconds, args.hz)
            res[xml] = (build_s, tick_s, ticks)
        nav_wall, nav_sim, nav_ticks = _navigator_goal(cfg)
    (b_build, b_tick, n), (x_build, x_tick, _) = res[False], res[True]
    print(
        f"{args.robots} patrol robots, {args.seconds:.0f} simulated s at {args.hz:.0f} Hz ({n} ticks per variant)"
    )
    print(
        f"build:  builder {1e3 * b_build / args.robots:.2f} ms/robot   XML {1e3 * x_build / args.robots:.2f} ms/robot   ratio {x_build / b_build:.1f}x"
    )
    print(
        f"tick:   builder {1e6 * b_tick / n:.1f} us/tick   XML {1e6 * x_tick / n:.1f} us/tick   ratio {x_tick / b_tick:.2f}x"
    )
    print(
        f"navigator: one NavigateToPose of {nav_sim:.1f} simulated s in {nav_wall:.2f} wall s ({nav_ticks} tree ticks, {1e6 * nav_wall / max(1, nav_ticks):.0f} us per step+tick)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
