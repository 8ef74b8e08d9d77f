"""``fleet sim-ros --shards K``: the robots served from K processes, each simulating its share.

The shipped 6-robot warehouse over 2 shard processes (robots 1, 3, 5 in the first; 2, 4, 6 in
the second), lean profile, 4x real time. Clients are Nav2's own: rclpy action clients on
``nav2_msgs`` NavigateToPose, as ``nav2_simple_commander`` sends it (``commander.py``). And
however the sharded server is stopped (Ctrl-C to its process group, SIGTERM to the parent
alone, the parent killed), no shard process is left running.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from starts import LocalizedCommanders
from waiting import GOAL_S, wait_until

from fleet.ros.launch import ServerProcess
from fleet.types import Pose2D

pytestmark = pytest.mark.ros

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"
ROBOTS = [f"/robot{i}" for i in range(1, 7)]
#: Hang guard (wall s) for the parent and its shards to be ready (K Python processes start).
READY_S = 120.0
#: Hang guard (wall s) for every shard process to be gone after a stop.
GONE_S = 30.0


def _args(*extra: str) -> list[str]:
    return ["--speed", "4", "--profile", "lean", "--shards", "2", *extra]


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie, exited but not yet reaped, counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rpartition(")")[2].split()[0] != "Z"


@pytest.fixture(scope="module")
def truth_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("shard_processes") / "truth.json"


@pytest.fixture(scope="module")
def server(truth_file: Path) -> Iterator[ServerProcess]:
    with ServerProcess.for_config(
        WAREHOUSE, *_args("--truth", str(truth_file)), ready_timeout_s=READY_S
    ) as srv:
        yield srv


def test_robots_of_both_shards_reach_nav2_goals(
    server: ServerProcess, ros_context: Any, truth_file: Path
) -> None:
    """Robot 1 (shard 1) and robot 2 (shard 2), each a NavigateToPose goal through rclpy's
    action client: both succeed, and the merged ground truth has each robot at its goal."""
    from commander import TaskResult

    from fleet.ros.conversions import pose2d_to_pose_stamped

    info = server.info
    assert info["shards"] == 2 and sorted(info["robots"]) == ROBOTS
    pids = info.get("shard_pids", [])
    assert len(set(pids)) == 2 and server.proc.pid not in pids and all(_alive(p) for p in pids)
    goals = {"/robot1": Pose2D(2.0, 5.0, 1.57), "/robot2": Pose2D(3.5, 5.5, 1.57)}
    navs = LocalizedCommanders(ros_context, set())
    try:
        for ns, p in goals.items():
            navs[ns].waitUntilNav2Active()
            assert navs[ns].goToPose(pose2d_to_pose_stamped(p)), f"{ns} refused the goal"
        wait_until(lambda: all(n.isTaskComplete() for n in navs.values()), GOAL_S, "both goals")
        assert {ns: navs[ns].getResult() for ns in goals} == dict.fromkeys(goals, TaskResult.SUCCEEDED)
    finally:
        navs.close()
    assert server.stop() == 130
    truth = json.loads(truth_file.read_text())["robots"]
    assert sorted(truth) == ROBOTS  # every shard's robots, merged
    for ns, p in goals.items():
        x, y, _ = truth[ns]["pose"]
        assert abs(x - p.x) < 0.3 and abs(y - p.y) < 0.3, (ns, truth[ns]["pose"])
    assert not [p for p in pids if _alive(p)]


def _stopped(how: str) -> tuple[int | None, list[int]]:
    """Start a 2-shard server, stop it ``how``; its exit status and the shard pids."""
    srv = ServerProcess.for_config(WAREHOUSE, *_args(), ready_timeout_s=READY_S)
    pids = srv.info.get("shard_pids", [])
    try:
        assert len(pids) == 2 and all(_alive(p) for p in pids)
        if how == "ctrl-c":  # a terminal's Ctrl-C: SIGINT to the whole foreground group
            os.killpg(srv.proc.pid, signal.SIGINT)
        else:
            os.kill(srv.proc.pid, signal.SIGTERM if how == "sigterm" else signal.SIGKILL)
        srv.proc.wait(timeout=GONE_S)
        wait_until(lambda: not any(_alive(p) for p in pids), GONE_S, f"every shard gone after {how}")
        return srv.proc.returncode, pids
    finally:
        srv.stop()


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm", "sigkill"])
def test_stopping_the_parent_leaves_no_shard_behind(how: str) -> None:
    """Ctrl-C and SIGTERM stop every shard cleanly (exit 130); a killed parent takes its shards
    with it (each asked the kernel for SIGTERM at its parent's death)."""
    code, _pids = _stopped(how)
    assert code == (-signal.SIGKILL if how == "sigkill" else 130)


def test_more_shards_than_robots_is_an_error(tmp_path: Path) -> None:
    from fleet.ros.nav2_server import main

    assert main([str(WAREHOUSE), "--robots", "2", "--shards", "3"]) == 2


def test_the_shards_get_the_command_line_without_the_parents_options() -> None:
    from fleet.ros.shard_processes import child_argv, shard_of

    argv = [
        "c.yaml",
        "--shards",
        "4",
        "--speed",
        "2",
        "--truth=t.json",
        "--plot",
        "p.png",
        "--ready-file",
        "r",
    ]
    assert child_argv(argv) == ["c.yaml", "--speed", "2"]
    assert shard_of("2/4") == (1, 4)
    for bad in ("0/4", "5/4", "x", "2/"):
        with pytest.raises(ValueError, match="shard-of"):
            shard_of(bad)


def test_shard_domains_put_each_shard_on_its_own_ros_domain() -> None:
    """``--shard-domains``: shard I on ``ROS_DOMAIN_ID + I - 1``. A client on the second
    domain drives robot 2 (shard 2) to its goal, and sees none of shard 1's robots. The two
    domains are claimed (:func:`fleet.ros.domains.claim_domains`): no other test or run on this
    machine is on either."""
    from fleet.ros.action_graph import served_actions
    from fleet.ros.backend import OWN_NODES, make_ros_backends
    from fleet.ros.domains import claim_domains
    from fleet.types import GoalStatus, NavigateToPose

    with contextlib.ExitStack() as stack:
        base = stack.enter_context(claim_domains(2)).first
        env = {**os.environ, "ROS_DOMAIN_ID": str(base)}
        srv = stack.enter_context(
            ServerProcess.for_config(WAREHOUSE, *_args("--shard-domains"), env=env, ready_timeout_s=READY_S)
        )
        assert srv.info.get("shard_domain_ids") == [base, base + 1]
        with make_ros_backends(["/robot2"], domain_id=base + 1, wait_s=GOAL_S, server_timeout_s=GOAL_S) as rb:
            goal = rb["/robot2"].send_goal(NavigateToPose(Pose2D(3.5, 5.5, 1.57)))
            wait_until(lambda: rb["/robot2"].goal_state(goal).status.terminal, GOAL_S, "robot 2's goal")
            assert rb["/robot2"].goal_state(goal).status is GoalStatus.SUCCEEDED
            seen = served_actions(rb["/robot2"].node, ["/robot1", "/robot2"], OWN_NODES)
            assert seen["/robot1"] == frozenset() and "navigate_to_pose" in seen["/robot2"]
