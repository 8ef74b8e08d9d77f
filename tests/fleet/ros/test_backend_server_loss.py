"""RosNavigationBackend against a Nav2 server that disappears mid-goal: the goal ends ABORTED
with SERVER_UNAVAILABLE within a bounded time instead of hanging."""

from __future__ import annotations

from pathlib import Path

import pytest
from waiting import DISCOVERY_S, wait_until

from fleet.ros.launch import ServerProcess
from fleet.types import ErrorCode, GoalStatus, NavigateToPose, Pose2D

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"

pytestmark = pytest.mark.ros

#: Hang guard (wall s) for a goal to end once its server is gone: the participant lease
#: (3 s, fleet/ros/discovery.xml) + the backend's server timeout (1 s here) + executor ticks,
#: about 4-5 s on an idle machine.
SERVER_LOSS_S = 30.0


def test_goal_aborts_cleanly_when_server_is_killed() -> None:
    from fleet.ros.backend import make_ros_backends

    srv = ServerProcess.for_config(WAREHOUSE, "--speed", "1", "--profile", "lean")
    try:
        with make_ros_backends(["/robot1"], wait_s=DISCOVERY_S, server_timeout_s=1.0) as rb:
            b = rb["/robot1"]
            gid = b.send_goal(NavigateToPose(Pose2D(2.5, 14.0, 0.0)))
            wait_until(lambda: b.goal_state(gid).status is GoalStatus.EXECUTING, DISCOVERY_S, "goal accepted")
            srv.kill()  # SIGKILL: no goodbye, discovery notices via the lease
            wait_until(
                lambda: b.goal_state(gid).status.terminal, SERVER_LOSS_S, "goal ended after server death"
            )
            state = b.goal_state(gid)
            assert state.status is GoalStatus.ABORTED
            assert state.error_code == ErrorCode.SERVER_UNAVAILABLE
            assert "unavailable" in state.error_msg
            # a goal sent while no server exists also ends, it does not stay PENDING
            gid2 = b.send_goal(NavigateToPose(Pose2D(2.5, 5.0, 0.0)))
            wait_until(
                lambda: b.goal_state(gid2).status.terminal, SERVER_LOSS_S, "goal without a server ended"
            )
            assert b.goal_state(gid2).error_code == ErrorCode.SERVER_UNAVAILABLE
    finally:
        srv.stop()
