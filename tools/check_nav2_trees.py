"""Load every navigator tree (BehaviorTree.CPP XML) of a directory, such as Nav2's own
``nav2_bt_navigator/behavior_trees``, and drive each one to a goal on the simulator through the
project's bt_navigator (:class:`nodes.navigator.BtNavigator`); print one table row per file.

    python tools/check_nav2_trees.py /opt/ros/jazzy/share/nav2_bt_navigator/behavior_trees
    python tools/check_nav2_trees.py DIR --config configs/warehouse_patrol.yaml --blocked

A file whose main tree reads ``{goals}`` is run as a NavigateThroughPoses goal through three
roadmap nodes across the warehouse, any other as a NavigateToPose goal to the far corner.
``--blocked`` puts an obstacle in the middle of the first aisle the robot would take, so the
tree has to replan (and recover) around it. A file that is not a navigator tree (no
``BehaviorTree`` element, or several and no ``main_tree_to_execute``: a subtree library) is
listed as ``skipped``.

Exit status: 0 when every navigator tree reached its goal, 1 otherwise (2: bad arguments).
Times are simulated seconds (the simulator steps as fast as it can).
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from py_trees.blackboard import Blackboard  # noqa: E402

from fleet.clock import SimClock  # noqa: E402
from fleet.config.loader import load_config  # noqa: E402
from fleet.errors import FleetError  # noqa: E402
from fleet.types import GoalStatus, NavigateThroughPoses, NavigateToPose, Pose2D  # noqa: E402
from nodes.navigator import BtNavigator  # noqa: E402
from sim.simulator import Simulator  # noqa: E402

#: Roadmap nodes of the warehouse configs the goals go to (through poses: all three in order).
TO_POSE_NODE = "a6_n"
THROUGH_NODES = ("a2_n", "a4_s", "a6_n")
#: Where ``--blocked`` puts its obstacle (x, y, radius in m): the middle of aisle 1.
BLOCK = (6.0, 11.5, 0.45)


@dataclass
class Row:
    """One file's outcome."""

    file: str
    action: str
    result: str
    code: int = 0
    sim_s: float = 0.0
    distance_m: float = 0.0
    recoveries: int = 0
    ticks: int = 0
    wall_s: float = 0.0
    note: str = ""


def kind_of(path: Path) -> str | None:
    """``navigate_through_poses`` / ``navigate_to_pose`` by the keys the file reads, ``None``
    for a file without a ``BehaviorTree``."""
    text = path.read_text(encoding="utf-8")
    trees = len(re.findall(r"<BehaviorTree\b", text))
    if trees == 0 or (trees > 1 and "main_tree_to_execute" not in text):
        return None
    return "navigate_through_poses" if re.search(r"\{goals\}", text) else "navigate_to_pose"


def run_file(path: Path, config: str, timeout_s: float, blocked: bool) -> Row:
    """Drive one robot of ``config`` with the tree of ``path`` (see the module docstring)."""
    kind = kind_of(path)
    if kind is None:
        return Row(path.name, "-", "skipped", note="no main tree (a subtree library)")
    Blackboard.clear()
    cfg = load_config(config, robots=1)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    spec = cfg.robots[0]
    sim.add_robot(spec)
    if blocked:
        sim.add_obstacle(*BLOCK)
    nav = BtNavigator(sim.backend(spec.namespace), sim.clock, battery=cfg.sim.battery)
    rm = cfg.roadmap
    goal: NavigateToPose | NavigateThroughPoses
    if kind == "navigate_to_pose":
        (pose,) = rm.poses_for([TO_POSE_NODE])
        goal = NavigateToPose(Pose2D(pose.x, pose.y, 0.0), behavior_tree=str(path))
    else:
        goal = NavigateThroughPoses(tuple(rm.poses_for(list(THROUGH_NODES))), behavior_tree=str(path))
    t0 = time.monotonic()
    gid = nav.send_goal(goal)
    start = sim.clock.now()
    state = nav.goal_state(gid)
    while not state.status.terminal and sim.clock.now() - start < timeout_s:
        sim.step()
        nav.tick()
        state = nav.goal_state(gid)
    if not state.status.terminal:
        nav.cancel_goal(gid)
    traj = sim.trajectory(spec.namespace)
    dist = sum(((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2) ** 0.5 for a, b in zip(traj, traj[1:], strict=False))
    result = state.status.name if state.status.terminal else "TIMEOUT"
    return Row(
        path.name,
        kind,
        result,
        state.error_code,
        sim.clock.now() - start,
        dist,
        state.feedback.number_of_recoveries or 0,
        nav.ticks,
        time.monotonic() - t0,
        "" if state.status == GoalStatus.SUCCEEDED else state.error_msg[:120],
    )


def print_table(rows: list[Row]) -> None:
    """The rows as a fixed-width table on stdout."""
    w = max([len(r.file) for r in rows] + [4])
    print(
        f"{'file':<{w}}  {'action':<22}  {'result':<9}  {'code':>4}  {'sim s':>6}  {'dist m':>6}  {'recov':>5}  {'ticks':>5}  {'wall s':>6}"
    )
    for r in rows:
        print(
            f"{r.file:<{w}}  {r.action:<22}  {r.result:<9}  {r.code:>4}  {r.sim_s:>6.1f}  {r.distance_m:>6.1f}  "
            f"{r.recoveries:>5}  {r.ticks:>5}  {r.wall_s:>6.2f}"
        )
        if r.note:
            print(f"{'':<{w}}  {r.note}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="check_nav2_trees.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", help="a directory of navigator trees (*.xml), e.g. Nav2's behavior_trees")
    ap.add_argument(
        "--config", default=str(ROOT / "configs" / "warehouse_patrol.yaml"), help="fleet config (a warehouse)"
    )
    ap.add_argument("--timeout", type=float, default=300.0, help="simulated seconds per goal (default 300)")
    ap.add_argument("--blocked", action="store_true", help="block the middle of aisle 1 with an obstacle")
    args = ap.parse_args(argv)
    files = sorted(Path(args.dir).glob("*.xml"))
    if not files:
        print(f"error: no *.xml in {args.dir}", file=sys.stderr)
        return 2
    rows: list[Row] = []
    for f in files:
        try:
            rows.append(run_file(f, args.config, args.timeout, args.blocked))
        except FleetError as exc:
            rows.append(Row(f.name, "-", "LOADERROR", note=str(exc)[:160]))
    print_table(rows)
    bad = [r for r in rows if r.result not in ("SUCCEEDED", "skipped")]
    print(f"{len(rows) - len(bad)} of {len(rows)} files reached their goal (or were skipped)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
