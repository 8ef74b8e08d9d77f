"""A navigation client of a long run stays bounded: goals that ended are forgotten beyond
:data:`fleet.bus.nav_client.KEEP_ENDED` (oldest first); running ones never are. Real Zenoh
session on loopback, no simulator (every goal ends ABORTED for want of a server)."""

from __future__ import annotations

from ports import free_endpoint

from fleet.bus.nav_client import KEEP_ENDED, ZenohNavBackend
from fleet.bus.session import open_session
from fleet.types import GoalStatus, NavigateToPose, Pose2D


def test_ended_goals_are_forgotten_beyond_the_bound_running_ones_kept() -> None:
    session = open_session(free_endpoint(), "router")
    try:
        nav = ZenohNavBackend(session, "/robot1", timeout_s=1e-6)
        ids = []
        for i in range(3 * KEEP_ENDED):
            gid = nav.send_goal(NavigateToPose(Pose2D(float(i % 7), 1.0, 0.0)))
            assert nav.goal_state(gid).status is GoalStatus.ABORTED  # no server: it ends at once
            ids.append(gid)
        nav.timeout_s = 1e9
        running = nav.send_goal(NavigateToPose(Pose2D(1.0, 1.0, 0.0)))
        for _ in range(300):
            nav.goal_state(nav.send_goal(NavigateToPose(Pose2D(2.0, 1.0, 0.0))))
        assert nav.goal_state(running).status is GoalStatus.PENDING  # kept, whatever its age
        assert nav.goal_state(ids[-1]).status is GoalStatus.ABORTED  # a recent ended one: kept
        remembered = sum(1 for g in ids if _known(nav, g))
        assert remembered <= KEEP_ENDED
        nav.close()
    finally:
        session.close()


def _known(nav: ZenohNavBackend, gid: str) -> bool:
    try:
        nav.goal_state(gid)
    except KeyError:
        return False
    return True
