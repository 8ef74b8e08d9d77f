"""A goal the ROS backend (:mod:`fleet.ros.backend`) sent to a robot's Nav2 server, as the
server last reported it, and the map from ``action_msgs`` statuses to :class:`GoalStatus`."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from fleet.ros.env import apply_ros_env_defaults

apply_ros_env_defaults()

from action_msgs.msg import GoalStatus as RosGoalStatus  # noqa: E402
from rclpy.action.client import ClientGoalHandle  # noqa: E402
from rclpy.task import Future  # noqa: E402

from fleet.types import Feedback, Goal, GoalState, GoalStatus, Path  # noqa: E402

#: ``action_msgs`` terminal statuses as the fleet's.
STATUS_MAP = {
    RosGoalStatus.STATUS_SUCCEEDED: GoalStatus.SUCCEEDED,
    RosGoalStatus.STATUS_CANCELED: GoalStatus.CANCELED,
    RosGoalStatus.STATUS_ABORTED: GoalStatus.ABORTED,
}


@dataclass
class RemoteGoal:
    """One goal the ROS backend sent: its state as the server last reported it (the backend's
    lock guards it)."""

    goal_id: str
    kind: str
    goal: Goal
    status: GoalStatus = GoalStatus.PENDING
    feedback: Feedback = field(default_factory=Feedback)
    error_code: int = 0
    error_msg: str = ""
    missed: tuple[int, ...] = ()
    path: Path = ()
    #: ``None`` until the request is sent, the request's future until the server answers,
    #: then the server's goal handle.
    handle: ClientGoalHandle | Future | None = None
    cancel_wanted: bool = False
    sent_at: float = 0.0
    unavailable_since: float | None = None

    def snapshot(self) -> GoalState:
        return GoalState(
            self.goal_id,
            self.kind,
            self.status,
            self.feedback,
            self.error_code,
            self.error_msg,
            self.missed,
            self.path,
        )

    def finish(self, status: GoalStatus, code: int = 0, msg: str = "") -> None:
        if self.status.terminal:
            return
        self.status, self.error_code, self.error_msg = status, int(code), msg


def succeed_when_answered(rec: RemoteGoal, calls: list[Future], lock: threading.RLock) -> None:
    """Mark ``rec`` sent now; it SUCCEEDS (under ``lock``) once every one of ``calls`` (service
    requests in flight) is answered."""
    done = Future()
    rec.sent_at = time.monotonic()
    rec.handle = done

    def answered(_f: Future) -> None:
        if all(f.done() for f in calls) and not done.done():
            done.set_result(True)
            with lock:
                rec.finish(GoalStatus.SUCCEEDED)

    for f in calls:
        f.add_done_callback(answered)
