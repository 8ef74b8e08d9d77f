"""``fleet sim-ros`` as Nav2's bt_navigator, over rclpy across processes: NavigateToPose and
NavigateThroughPoses run a navigator tree (BehaviorTree.CPP XML) per goal; the goal's
``behavior_tree`` picks the file, ``--nav-to-pose-xml`` sets the default; a tree that cannot
be loaded aborts the goal; a goal on one action does not preempt another action's goal.

World: ``configs/warehouse_patrol.yaml`` (robots 1-6 start at (i, 3) facing +y; the cross
aisle at y = 5 and the aisle at x = 6 are free). The server's default NavigateToPose tree is
``tests/nodes/data/trees/to_pose_every_node.xml``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from waiting import GOAL_S

from fleet.ros.env import ros_available
from fleet.types import ErrorCode, Pose2D

if ros_available() or TYPE_CHECKING:  # else every test here is skipped (conftest.py)
    from commander import Commander, TaskResult

    from fleet.ros.conversions import pose2d_to_pose_stamped, pose_stamped_to_pose2d
    from fleet.ros.launch import ServerProcess

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[3]
WAREHOUSE = ROOT / "configs" / "warehouse_patrol.yaml"
TREES = ROOT / "tests" / "nodes" / "data" / "trees"
DEFAULT_TREE = TREES / "to_pose_every_node.xml"


@pytest.fixture(scope="module")
def navigator_server() -> Iterator[ServerProcess]:
    with ServerProcess.for_config(
        WAREHOUSE, "--speed", "4", "--amcl-hz", "2", "--nav-to-pose-xml", str(DEFAULT_TREE)
    ) as srv:
        yield srv


@pytest.fixture()
def make(navigator_server: Any, ros_context: Any) -> Iterator[Any]:
    made: list[Commander] = []

    def _make(ns: str) -> Commander:
        made.append(Commander(ns, ros_context))
        return made[-1]

    yield _make
    for n in made:
        n.close()


def _ps(x: float, y: float, th: float = math.pi / 2) -> Any:
    return pose2d_to_pose_stamped(Pose2D(x, y, th))


def _run(nav: Commander, timeout_s: float = GOAL_S) -> list[Any]:
    feedback = []
    deadline = time.monotonic() + timeout_s
    while not nav.isTaskComplete():
        if nav.getFeedback() is not None:
            feedback.append(nav.getFeedback())
        assert time.monotonic() < deadline, f"task did not finish within {timeout_s:.0f} s"
    return feedback


def _wait_executing(nav: Commander) -> None:
    nav.spin_until(lambda: nav.getFeedback() is not None, GOAL_S, "first feedback")


def test_default_tree_from_the_command_line_runs_the_goal(make: Any) -> None:
    nav = make("/robot1")
    assert nav.goToPose(_ps(-50.0, -50.0))  # off the map: the planner fails, recoveries run
    _run(nav, 3 * GOAL_S)
    res = nav.result_message()
    assert nav.getResult() is TaskResult.FAILED
    assert res.error_code == ErrorCode.GOAL_OUTSIDE_MAP
    assert DEFAULT_TREE.name in res.error_msg
    assert nav.goToPose(_ps(1.0, 5.0, 0.0))
    fb = _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED
    assert fb and fb[-1].distance_remaining < fb[0].distance_remaining + 1e-6


def test_behavior_tree_field_picks_the_tree(make: Any) -> None:
    nav = make("/robot2")
    through = str(TREES / "through_poses_every_node.xml")
    assert nav.goThroughPoses([_ps(2.0, 5.0, 0.0), _ps(-50.0, -50.0)], behavior_tree=through)
    _run(nav)
    res = nav.result_message()
    assert nav.getResult() is TaskResult.FAILED
    assert "through_poses_every_node.xml" in res.error_msg
    assert nav.goThroughPoses([_ps(2.0, 5.0, 0.0), _ps(4.0, 5.0, 0.0)], behavior_tree=through)
    fb = _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message().error_msg
    assert any(f.number_of_poses_remaining >= 1 for f in fb)
    assert pose_stamped_to_pose2d(fb[-1].current_pose).distance_to(Pose2D(4.0, 5.0)) < 1.0


def test_unloadable_tree_aborts_the_goal(make: Any, tmp_path: Path) -> None:
    nav = make("/robot3")
    bad = tmp_path / "bad.xml"
    bad.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="T">\n<FollowPaht path="{path}"/>\n</BehaviorTree></root>'
    )
    for tree in (str(bad), str(tmp_path / "missing.xml")):
        assert nav.goToPose(_ps(3.0, 5.0), behavior_tree=tree)
        _run(nav)
        assert nav.getResult() is TaskResult.FAILED
        assert "Cannot load the behavior tree" in nav.result_message().error_msg
    assert nav.goToPose(_ps(3.0, 5.0, 0.0))
    _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED


def test_goals_on_other_actions_do_not_preempt_navigation(make: Any) -> None:
    nav, other = make("/robot4"), make("/robot4")
    for key in ("compute_path_to_pose", "navigate_through_poses"):
        other._wait_server(key)  # discovery before the goal, so the goal is still running
    assert nav.goToPose(_ps(6.0, 18.0))
    _wait_executing(nav)
    path = other.getPath(_ps(0, 0), _ps(9.0, 9.0))  # the planner action beside the navigator
    assert path is not None and len(path.poses) >= 2
    assert nav.status is None or not nav.isTaskComplete(), nav.result_message()
    assert not other.goThroughPoses([_ps(4.0, 5.0)])  # bt_navigator refuses the other navigator
    _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message().error_msg
