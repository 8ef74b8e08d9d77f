"""RosNavigationBackend against a Nav2 server that disappears mid-goal: the goal ends ABORTED
with SERVER_UNAVAILABLE within a bounded time instead of hanging."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from fleet.ros.backend import make_ros_backends
from fleet.ros.launch import ServerProcess
from fleet.types import ErrorCode, GoalStatus, NavigateToPose, Pose2D

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"

pytestmark = pytest.mark.ros


def test_goal_aborts_cleanly_when_server_is_killed() -> None:
    srv = ServerProcess.for_config(WAREHOUSE, "--speed", "1", "--profile", "lean")
    try:
        with make_ros_backends(["/robot1"], wait_s=20.0, server_timeout_s=1.0) as rb:
            b = rb["/robot1"]
            gid = b.send_goal(NavigateToPose(Pose2D(2.5, 14.0, 0.0)))
            deadline = time.monotonic() + 10.0
            while b.goal_state(gid).status is not GoalStatus.EXECUTING:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            srv.kill()  # SIGKILL: no goodbye, discovery notices via the lease
            t0 = time.monotonic()
            while not b.goal_state(gid).status.terminal:
                assert time.monotonic() - t0 < 15.0, "goal still running after the server died"
                time.sleep(0.05)
            state = b.goal_state(gid)
            assert state.status is GoalStatus.ABORTED
            assert state.error_code == ErrorCode.SERVER_UNAVAILABLE
            assert "unavailable" in state.error_msg
            # a goal sent while no server exists also ends, it does not stay PENDING
            gid2 = b.send_goal(NavigateToPose(Pose2D(2.5, 5.0, 0.0)))
            t0 = time.monotonic()
            while not b.goal_state(gid2).status.terminal:
                assert time.monotonic() - t0 < 10.0
                time.sleep(0.05)
            assert b.goal_state(gid2).error_code == ErrorCode.SERVER_UNAVAILABLE
    finally:
        srv.stop()
