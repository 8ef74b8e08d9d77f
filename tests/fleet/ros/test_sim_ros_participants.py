"""``fleet sim-ros --participants K``: the robots' Nav2 interfaces spread over K DDS participants of
one server process, one simulated world. Every robot is discovered and answers its actions,
whichever participant serves it, and robots of different participants still see each other.

The shipped 6-robot warehouse, served by 3 participants (robots 1 and 4, 2 and 5, 3 and 6
share one), lean profile, at 2x real time in a child process.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from waiting import DISCOVERY_S, GOAL_S, wait_until

from fleet.ros.launch import ServerProcess
from fleet.types import GoalStatus, NavigateToPose, Pose2D, Wait

if TYPE_CHECKING:
    from fleet.ros.backend import RosBackends

pytestmark = pytest.mark.ros

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"
ROBOTS = [f"/robot{i}" for i in range(1, 7)]


@pytest.fixture(scope="module")
def truth_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("shards") / "truth.json"


@pytest.fixture(scope="module")
def server(truth_file: Path) -> Iterator[ServerProcess]:
    with ServerProcess.for_config(
        WAREHOUSE, "--speed", "2", "--profile", "lean", "--participants", "3", "--truth", str(truth_file)
    ) as srv:
        yield srv


@pytest.fixture(scope="module")
def backends(server: ServerProcess) -> Iterator[RosBackends]:
    from fleet.ros.backend import make_ros_backends

    rb = make_ros_backends(ROBOTS, wait_s=DISCOVERY_S)
    try:
        yield rb
    finally:
        rb.close()


def test_every_robot_of_every_participant_is_discovered_and_answers(
    server: ServerProcess, backends: RosBackends
) -> None:
    assert server.info["participants"] == 3 and server.info["shards"] == 1
    assert sorted(server.info["robots"]) == sorted(ROBOTS)
    ids = {ns: backends[ns].send_goal(Wait(0.5)) for ns in ROBOTS}
    wait_until(
        lambda: all(backends[ns].goal_state(g).status.terminal for ns, g in ids.items()),
        GOAL_S,
        "a Wait goal on every robot",
    )
    assert {ns: backends[ns].goal_state(g).status for ns, g in ids.items()} == dict.fromkeys(
        ROBOTS, GoalStatus.SUCCEEDED
    )


def test_the_graph_read_node_by_node_finds_every_robots_servers(backends: RosBackends) -> None:
    """The fleet's readiness check reads the graph node by node (``served_actions``): every
    robot's seven navigation servers are found, whichever participant serves them, and a
    namespace nobody serves has none; every robot then reports ``navigation_ready``."""
    from fleet.ros.action_graph import served_actions
    from fleet.ros.backend import BACKEND_KINDS, OWN_NODES

    node = backends["/robot1"].node
    served = served_actions(node, [*ROBOTS, "/robot99"], OWN_NODES)
    assert {ns: set(BACKEND_KINDS) <= served[ns] for ns in ROBOTS} == dict.fromkeys(ROBOTS, True)
    assert served["/robot99"] == frozenset()
    # services too (the navigator's lifecycle state); a lean node serves no type descriptions
    assert "bt_navigator/get_state" in served["/robot1"]
    assert not any(n.endswith("get_type_description") for n in served["/robot1"])
    assert backends.wait_for_servers(DISCOVERY_S) == []
    assert backends.wait_for_servers(0.0) == []  # a zero timeout still looks once
    assert backends.wait_for_servers(0.0, ["no_such_action"]) == ROBOTS
    wait_until(
        lambda: all(backends[ns].robot_state().navigation_ready for ns in ROBOTS),
        DISCOVERY_S,
        "navigation_ready on every robot",
    )


def test_backends_making_only_the_navigators_at_start_answer_other_goals_too(server: ServerProcess) -> None:
    """``eager`` names the action clients made at start (fewer endpoints to discover): a robot
    still counts discovered only with all seven servers seen, and a goal of another kind
    (Wait) makes its client on first use and is answered."""
    from fleet.ros.backend import make_ros_backends

    eager = ("navigate_to_pose", "navigate_through_poses")
    with make_ros_backends(ROBOTS[:2], wait_s=DISCOVERY_S, eager=eager, server_timeout_s=GOAL_S) as rb:
        assert all(set(rb[ns]._clients) == set(eager) for ns in ROBOTS[:2])
        wait_until(
            lambda: all(rb[ns].robot_state().navigation_ready for ns in ROBOTS[:2]),
            DISCOVERY_S,
            "navigation_ready with two eager clients",
        )
        ids = {ns: rb[ns].send_goal(Wait(0.5)) for ns in ROBOTS[:2]}
        wait_until(
            lambda: all(rb[ns].goal_state(g).status.terminal for ns, g in ids.items()),
            GOAL_S,
            "a Wait goal through a client made on first use",
        )
        assert [rb[ns].goal_state(g).status for ns, g in ids.items()] == [GoalStatus.SUCCEEDED] * 2


def test_robots_of_other_participants_drive_in_the_one_world(
    server: ServerProcess, backends: RosBackends, truth_file: Path
) -> None:
    """Robot 2 (second participant) and robot 3 (third) drive to goals; the world the server
    steps moves both (its ground truth at the end has them there)."""
    goals = {"/robot2": Pose2D(2.0, 5.0, 1.57), "/robot3": Pose2D(3.0, 5.0, 1.57)}
    ids = {ns: backends[ns].send_goal(NavigateToPose(p)) for ns, p in goals.items()}
    wait_until(
        lambda: all(backends[ns].goal_state(g).status.terminal for ns, g in ids.items()),
        GOAL_S,
        "NavigateToPose on robots 2 and 3",
    )
    assert [backends[ns].goal_state(g).status for ns, g in ids.items()] == [GoalStatus.SUCCEEDED] * 2
    assert server.stop() == 130
    truth = json.loads(truth_file.read_text())["robots"]
    for ns, p in goals.items():
        x, y, _ = truth[ns]["pose"]
        assert abs(x - p.x) < 0.3 and abs(y - p.y) < 0.3, (ns, truth[ns]["pose"])


def test_a_goal_is_sent_once_whoever_sends_it_first(backends: RosBackends) -> None:
    """``send_goal`` queues the request and the backend's watchdog may send it first: the
    queued send then does nothing (twice sent, the second request preempted the first)."""
    from fleet.ros.remote_goal import RemoteGoal

    b = backends["/robot1"]
    rec = RemoteGoal("/robot1#x", "wait", Wait(0.5))
    rec.handle = object()  # type: ignore[assignment]  # "request sent"

    def no_client(kind: str) -> None:
        raise AssertionError(f"a second {kind} request was sent")

    b._client = no_client  # type: ignore[method-assign,assignment]
    try:
        b._send_remote(rec)
    finally:
        del b._client
