"""Robot health from status records: silence, progress, stuck, charging, robots next to each
other, and waypoints blocked by something standing on them."""

from __future__ import annotations

from fleet.coordination import health
from fleet.coordination.views import Assignment, Observation, RobotView
from fleet.types import Mode, Pose2D, TaskKind


def robot(name: str, x: float, mode: str = Mode.PATROL, task_id: str | None = "p-0001") -> RobotView:
    return RobotView(
        name, last_seen=0.0, obs=Observation(t=0.0, pose=Pose2D(x, 0), mode=mode, task_id=task_id)
    )


def test_silent_after_the_timeout_only_while_alive() -> None:
    v = robot("r", 0)
    assert not health.silent(v, 3.0, 3.0) and health.silent(v, 3.1, 3.0)
    v.alive = False
    assert not health.silent(v, 10.0, 3.0)


def test_progress_and_stalled() -> None:
    v = robot("r", 0)
    a = Assignment("p-0001", "loop", TaskKind.PATROL, "r", t_assigned=0.0)
    health.note_progress(v, Pose2D(0, 0), 1.0)
    health.note_progress(v, Pose2D(health.PROGRESS_M, 0), 2.0)  # not farther than PROGRESS_M
    assert v.progress_t == 1.0
    assert not health.stalled(v, a, 31.0, 30.0) and health.stalled(v, a, 31.1, 30.0)
    health.note_progress(v, Pose2D(health.PROGRESS_M + 0.01, 0), 30.0)
    assert v.progress_t == 30.0 and not health.stalled(v, a, 31.1, 30.0)
    idle = robot("i", 0, mode=Mode.IDLE)
    other_id = robot("o", 0, task_id="p-0002")
    assert not health.stalled(idle, a, 100.0, 30.0)  # not driving
    assert not health.stalled(other_id, a, 100.0, 30.0)  # executing something else
    assert health.charging(robot("c", 0, mode=Mode.CHARGING)) and not health.charging(idle)


def test_someone_near_counts_live_robots_with_a_pose() -> None:
    me, near, far = robot("me", 0), robot("near", 1.0), robot("far", 5.0)
    assert health.someone_near([me, near, far], me, Pose2D(0, 0))
    near.alive = False
    assert not health.someone_near([me, near, far], me, Pose2D(0, 0))


def test_blocked_waypoints_are_skipped_until_they_expire() -> None:
    lap = (Pose2D(0, 0), Pose2D(10, 0), Pose2D(20, 0))
    b = health.BlockedWaypoints()
    assert b.mark_near(lap, Pose2D(15, 0), 0.0) is None  # 5 m from any waypoint
    assert b.mark_near(lap, Pose2D(19.3, 0), 0.0) == Pose2D(20, 0)
    assert b.skip(lap, 1.0) == lap[:2]
    assert b.skip(lap[1:], 1.0) == lap[1:]  # fewer than 2 would remain: unchanged
    assert b.skip(lap, health.BLOCKED_WAYPOINT_S) == lap and b.items == []
