"""BehaviorTree.CPP v4 XML navigator trees (``nodes/xml_tree.py``, ``nodes/navigator.py``) on
the real simulator: trees written for this project that use every node and port of Nav2
Jazzy's default navigator trees reach their goals; every mistake in a file is an error naming
the file, the line and the node.

World: ``configs/warehouse_patrol.yaml`` with one robot at (1, 3)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.errors import TreeError
from fleet.types import GoalStatus, NavigateThroughPoses, NavigateToPose, Pose2D
from nodes.blackboard import robot_blackboard
from nodes.catalog import default_registry
from nodes.navigator import DEFAULT_NAV_THROUGH_POSES_XML, DEFAULT_NAV_TO_POSE_XML, BtNavigator
from nodes.xml_tree import load_tree
from sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[2]
TREES = Path(__file__).resolve().parent / "data" / "trees"
WAREHOUSE = ROOT / "configs" / "warehouse_patrol.yaml"

#: The nodes of Nav2 Jazzy's navigator trees (nav2_bt_navigator/behavior_trees) and the ports
#: they set: interface names, which a loader of those files must know.
NAV2_JAZZY_NODES: dict[str, tuple[str, ...]] = {
    "BackUp": ("backup_dist", "backup_speed", "error_code_id"),
    "CancelControl": (),
    "ClearEntireCostmap": ("service_name",),
    "ComputePathThroughPoses": ("error_code_id", "goals", "path", "planner_id"),
    "ComputePathToPose": ("error_code_id", "goal", "path", "planner_id"),
    "ControllerSelector": ("default_controller", "selected_controller", "topic_name"),
    "DistanceController": ("distance",),
    "Fallback": (),
    "FollowPath": ("controller_id", "error_code_id", "path"),
    "GoalUpdated": (),
    "GoalUpdatedController": (),
    "PathLongerOnApproach": ("length_factor", "path", "prox_len"),
    "PipelineSequence": (),
    "PlannerSelector": ("default_planner", "selected_planner", "topic_name"),
    "RateController": ("hz",),
    "ReactiveFallback": (),
    "ReactiveSequence": (),
    "RecoveryNode": ("number_of_retries",),
    "RemovePassedGoals": ("input_goals", "output_goals", "radius"),
    "RetryUntilSuccessful": ("num_attempts",),
    "RoundRobin": (),
    "Sequence": (),
    "SequenceWithMemory": (),
    "SpeedController": ("max_rate", "max_speed", "min_rate", "min_speed"),
    "Spin": ("error_code_id", "spin_dist"),
    "Wait": ("wait_duration",),
    "WouldAControllerRecoveryHelp": ("error_code",),
    "WouldAPlannerRecoveryHelp": ("error_code",),
}


def _tags_and_attrs(files: list[Path]) -> dict[str, set[str]]:
    seen: dict[str, set[str]] = {}
    for f in files:
        for tag, attrs in re.findall(r"<([A-Za-z]\w*)([^>]*)>", f.read_text(encoding="utf-8")):
            seen.setdefault(tag, set()).update(re.findall(r"(\w+)=", attrs))
    return seen


def _world() -> tuple[Simulator, str, object]:
    cfg = load_config(WAREHOUSE, robots=1)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    sim.add_robot(cfg.robots[0])
    return sim, cfg.robots[0].namespace, cfg.roadmap


def _drive(sim: Simulator, nav: BtNavigator, gid: str, limit_s: float = 300.0) -> GoalStatus:
    start = sim.clock.now()
    while not nav.goal_state(gid).status.terminal and sim.clock.now() - start < limit_s:
        sim.step()
        nav.tick()
    return nav.goal_state(gid).status


def test_every_nav2_node_and_port_is_registered_and_used_by_the_test_trees() -> None:
    reg = default_registry()
    seen = _tags_and_attrs(sorted(TREES.glob("*.xml")))
    for name, ports in NAV2_JAZZY_NODES.items():
        spec = reg.get(name)
        assert spec is not None, name
        assert name in seen, f"no test tree uses {name}"
        for port in ports:
            assert spec.port(port) is not None, f"{name} has no port {port}"
            assert port in seen[name], f"no test tree sets {name}.{port}"


@pytest.mark.parametrize("tree", ["to_pose_every_node.xml", "through_poses_every_node.xml"])
def test_every_node_tree_reaches_its_goal(tree: str) -> None:
    sim, ns, rm = _world()
    nav = BtNavigator(sim.backend(ns), sim.clock)
    if tree.startswith("to_pose"):
        (p,) = rm.poses_for(["a6_n"])  # type: ignore[attr-defined]
        goal: NavigateToPose | NavigateThroughPoses = NavigateToPose(p, behavior_tree=str(TREES / tree))
        last = p
    else:
        poses = rm.poses_for(["a2_n", "a4_s", "a6_n"])  # type: ignore[attr-defined]
        goal, last = NavigateThroughPoses(tuple(poses), behavior_tree=str(TREES / tree)), poses[-1]
    gid = nav.send_goal(goal)
    assert _drive(sim, nav, gid) is GoalStatus.SUCCEEDED, nav.goal_state(gid).error_msg
    here = sim.robot_state(ns).pose
    assert here is not None and here.distance_to(last) < 0.5
    assert nav.ticks > 100


def test_project_default_trees_reach_goals_through_poses() -> None:
    sim, ns, rm = _world()
    nav = BtNavigator(sim.backend(ns), sim.clock)
    assert nav.defaults["navigate_to_pose"] == str(DEFAULT_NAV_TO_POSE_XML)
    poses = rm.poses_for(["a1_2", "a3_2"])  # type: ignore[attr-defined]
    gid = nav.send_goal(NavigateThroughPoses(tuple(poses)))
    assert _drive(sim, nav, gid) is GoalStatus.SUCCEEDED
    assert nav.defaults["navigate_through_poses"] == str(DEFAULT_NAV_THROUGH_POSES_XML)
    here = sim.robot_state(ns).pose
    assert here is not None and here.distance_to(poses[-1]) < 0.5


def test_unloadable_behavior_tree_aborts_the_goal_and_the_next_goal_runs(tmp_path: Path) -> None:
    sim, ns, _rm = _world()
    nav = BtNavigator(sim.backend(ns), sim.clock)
    bad = tmp_path / "bad.xml"
    bad.write_text('<root BTCPP_format="4"><BehaviorTree ID="T">\n<Spinn/>\n</BehaviorTree></root>')
    for tree in (str(bad), str(tmp_path / "missing.xml")):
        gid = nav.send_goal(NavigateToPose(Pose2D(2.5, 9.0), behavior_tree=tree))
        state = nav.goal_state(gid)
        assert state.status is GoalStatus.ABORTED
        assert "Cannot load the behavior tree" in state.error_msg
    assert "bad.xml:2" in nav.goal_state(f"{ns}#n1").error_msg
    gid = nav.send_goal(NavigateToPose(Pose2D(2.5, 9.0)))
    assert _drive(sim, nav, gid) is GoalStatus.SUCCEEDED


def test_new_goal_of_the_same_navigator_replaces_the_goal_on_the_running_tree() -> None:
    sim, ns, _rm = _world()
    nav = BtNavigator(sim.backend(ns), sim.clock)
    first = nav.send_goal(NavigateToPose(Pose2D(2.5, 14.0)))
    for _ in range(40):
        sim.step()
        nav.tick()
    second = nav.send_goal(NavigateToPose(Pose2D(6.0, 5.0)))
    assert nav.goal_state(first).status is GoalStatus.ABORTED
    assert "preempted" in nav.goal_state(first).error_msg
    assert _drive(sim, nav, second) is GoalStatus.SUCCEEDED
    here = sim.robot_state(ns).pose
    assert here is not None and here.distance_to(Pose2D(6.0, 5.0)) < 0.5


BAD_TREES = {
    "unknown node": (
        '<Sequence>\n<ComputePathToPoze goal="{goal}" path="{path}"/>\n</Sequence>',
        3,
        "ComputePathToPoze",
        "did you mean ComputePathToPose",
    ),
    "bad port": (
        '<Sequence>\n<Wait wait_durration="1.0"/>\n</Sequence>',
        3,
        "<Wait>",
        "did you mean wait_duration",
    ),
    "bad literal": ('<Sequence>\n<Wait wait_duration="soon"/>\n</Sequence>', 3, "<Wait>", "wait_duration"),
    "output literal": (
        '<ComputePathToPose goal="{goal}" path="fixed"/>',
        2,
        "<ComputePathToPose>",
        "blackboard key",
    ),
    "child count": ("<Inverter><Wait/><Wait/></Inverter>", 2, "<Inverter>", "exactly 1 child"),
    "unknown subtree": ('<SubTree ID="Nope"/>', 2, "Nope", "no tree with ID"),
    "malformed": ("<Sequence>\n", 4, "", "not well-formed"),
}


@pytest.mark.parametrize("case", sorted(BAD_TREES))
def test_bad_xml_is_an_error_naming_file_line_and_node(case: str, tmp_path: Path) -> None:
    body, line, node, reason = BAD_TREES[case]
    f = tmp_path / "tree.xml"
    f.write_text(f'<root BTCPP_format="4"><BehaviorTree ID="T">\n{body}\n</BehaviorTree></root>')
    sim, ns, _rm = _world()
    with pytest.raises(TreeError) as err:
        load_tree(f, ns, sim.backend(ns), sim.clock, None)
    msg = str(err.value)
    assert msg.startswith(f"{f}:{line}:"), msg
    assert node in msg and reason in msg, msg


class _Recorder:
    """The robot's backend, recording the kind of every goal sent (a real simulator inside)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.sent: list[Any] = []
        self.namespace = inner.namespace

    def send_goal(self, goal: Any) -> str:
        self.sent.append(goal)
        return str(self.inner.send_goal(goal))

    def goal_state(self, goal_id: str) -> Any:
        return self.inner.goal_state(goal_id)

    def cancel_goal(self, goal_id: str) -> None:
        self.inner.cancel_goal(goal_id)

    def robot_state(self) -> Any:
        return self.inner.robot_state()


def test_inspection_tree_acts_at_every_waypoint_of_the_route() -> None:
    sim, ns, rm = _world()
    backend = _Recorder(sim.backend(ns))
    tree = load_tree(ROOT / "nodes" / "trees" / "inspection.xml", ns, backend, sim.clock, None)
    bb = robot_blackboard(ns, name="test")
    route = rm.poses_for(["w_1", "w_2", "a1_2", "a1_1"])  # type: ignore[attr-defined]
    bb.route, bb.task_id, bb.charger = route, "t-1", Pose2D(1.0, 7.0)
    ticks = 0
    while int(bb.laps) < 1 and ticks < 6000:  # 600 s of 10 Hz ticks: a hang guard
        for _ in range(2):
            sim.step()
        tree.root.tick_once()
        ticks += 1
    assert int(bb.laps) == 1
    kinds = [g.kind for g in backend.sent]
    visits = [i for i, k in enumerate(kinds) if k == "navigate_to_pose"]
    assert len(visits) >= len(route)
    for i in visits[: len(route)]:  # drive there, turn a full circle, hold still
        assert kinds[i + 1 : i + 3] == ["spin", "wait"], kinds
        assert backend.sent[i + 1].target_yaw == pytest.approx(6.2832)
    goals = {(round(backend.sent[i].pose.x, 1), round(backend.sent[i].pose.y, 1)) for i in visits}
    assert goals == {(round(p.x, 1), round(p.y, 1)) for p in route}


#: (tree body, ticks, the root's status after them): BehaviorTree.CPP's control nodes and
#: decorators on leaves without goals (AlwaysSuccess / AlwaysFailure, Sleep on the sim clock).
CONTROL_CASES = {
    "Inverter": ("<Inverter><AlwaysFailure/></Inverter>", 1, "SUCCESS"),
    "ForceSuccess": ("<ForceSuccess><AlwaysFailure/></ForceSuccess>", 1, "SUCCESS"),
    "ForceFailure": ("<ForceFailure><AlwaysSuccess/></ForceFailure>", 1, "FAILURE"),
    "KeepRunningUntilFailure": (
        "<KeepRunningUntilFailure><AlwaysSuccess/></KeepRunningUntilFailure>",
        3,
        "RUNNING",
    ),
    "KeepRunningUntilFailure fails": (
        "<KeepRunningUntilFailure><AlwaysFailure/></KeepRunningUntilFailure>",
        1,
        "FAILURE",
    ),
    "Fallback": ("<Fallback><AlwaysFailure/><AlwaysSuccess/></Fallback>", 1, "SUCCESS"),
    "Sequence": ("<Sequence><AlwaysSuccess/><AlwaysFailure/></Sequence>", 1, "FAILURE"),
    "ReactiveSequence": (
        '<ReactiveSequence><AlwaysSuccess/><Sleep msec="500"/></ReactiveSequence>',
        2,
        "RUNNING",
    ),
    "IfThenElse": ("<IfThenElse><AlwaysFailure/><AlwaysFailure/><AlwaysSuccess/></IfThenElse>", 1, "SUCCESS"),
    "WhileDoElse": (
        "<WhileDoElse><AlwaysSuccess/><AlwaysFailure/><AlwaysSuccess/></WhileDoElse>",
        1,
        "FAILURE",
    ),
    "Parallel": (
        '<Parallel success_count="1" failure_count="2"><AlwaysSuccess/><AlwaysFailure/></Parallel>',
        1,
        "SUCCESS",
    ),
    "RetryUntilSuccessful": (
        '<RetryUntilSuccessful num_attempts="3"><AlwaysFailure/></RetryUntilSuccessful>',
        3,  # one attempt per tick (BehaviorTree.CPP makes them all in one tick)
        "FAILURE",
    ),
    "Repeat": ('<Repeat num_cycles="3"><AlwaysSuccess/></Repeat>', 3, "SUCCESS"),
    "Timeout": ('<Timeout msec="200"><Sleep msec="1000"/></Timeout>', 6, "FAILURE"),
    "Delay": ('<Delay delay_msec="200"><AlwaysSuccess/></Delay>', 6, "SUCCESS"),
    "RunOnce": ('<RunOnce then_skip="true"><AlwaysFailure/></RunOnce>', 2, "SUCCESS"),
    "RecoveryNode": (
        '<RecoveryNode number_of_retries="2"><AlwaysFailure/><AlwaysSuccess/></RecoveryNode>',
        1,
        "FAILURE",
    ),
    "RoundRobin": ("<RoundRobin><AlwaysFailure/><AlwaysSuccess/></RoundRobin>", 1, "SUCCESS"),
    "PipelineSequence": (
        '<PipelineSequence><AlwaysSuccess/><Sleep msec="500"/></PipelineSequence>',
        2,
        "RUNNING",
    ),
}


@pytest.mark.parametrize("case", sorted(CONTROL_CASES))
def test_control_nodes_behave_as_behaviortree_cpp(case: str) -> None:
    body, ticks, expected = CONTROL_CASES[case]
    sim, ns, _rm = _world()
    text = f'<root BTCPP_format="4"><BehaviorTree ID="T">{body}</BehaviorTree></root>'
    tree = load_tree(text, ns, sim.backend(ns), sim.clock, None)
    for _ in range(ticks):
        for _ in range(2):  # 0.1 s of simulated time per tick
            sim.step()
        tree.root.tick_once()
    assert tree.root.status.name == expected
