"""An agent's status record: the fields its tree gives (:class:`TreeView`), whether a new
record says something the last one published did not (:func:`status_changed`, for publishing
on change), and what an in-process coordinator reads of it (:func:`observation`)."""

from __future__ import annotations

import math
from typing import NamedTuple

from fleet.coordination.views import Observation, make_observation
from fleet.messages import StatusRecord
from fleet.types import Pose2D


class TreeView(NamedTuple):
    """The status record's fields that come from the tree and its blackboard."""

    bt: str
    leaf: str
    mode: str
    task_id: str | None
    laps: int
    progress: float
    picks_done: int
    result_id: str | None
    result: str
    steps_done: int


#: Moves smaller than these do not count as a change of the status (m, rad, fraction, m).
POSE_EPS_M = 0.05
THETA_EPS_RAD = 0.05
BATTERY_EPS = 0.005
PROGRESS_EPS = 0.01


def status_changed(old: StatusRecord, new: StatusRecord) -> bool:
    """Whether ``new`` says something ``old`` did not: any field but ``t`` and ``seq`` differs,
    except that the pose must move by :data:`POSE_EPS_M` / :data:`THETA_EPS_RAD`, the battery by
    :data:`BATTERY_EPS`, the lap progress by :data:`PROGRESS_EPS` and the odometer by
    :data:`POSE_EPS_M` to count."""
    p, q = old.pose, new.pose
    if (p is None) != (q is None):
        return True
    if p is not None and q is not None:
        if abs(p[0] - q[0]) > POSE_EPS_M or abs(p[1] - q[1]) > POSE_EPS_M:
            return True
        if abs(math.remainder(p[2] - q[2], math.tau)) > THETA_EPS_RAD:
            return True
    return (
        abs(old.battery - new.battery) > BATTERY_EPS
        or abs(old.progress - new.progress) > PROGRESS_EPS
        or abs(old.distance_m - new.distance_m) > POSE_EPS_M
        or old.mode != new.mode
        or old.task_id != new.task_id
        or old.bt != new.bt
        or old.leaf != new.leaf
        or old.charging != new.charging
        or old.stuck != new.stuck
        or old.laps != new.laps
        or old.collisions != new.collisions
        or old.picks_done != new.picks_done
        or old.health != new.health
        or old.diag != new.diag
        or old.result_id != new.result_id
        or old.result != new.result
        or old.steps_done != new.steps_done
        or old.epoch != new.epoch
        or old.order_seq != new.order_seq
        or old.grant_seq != new.grant_seq
        or old.malformed != new.malformed
        or old.rejected != new.rejected
    )


def observation(rec: StatusRecord, pose: Pose2D | None, view: TreeView) -> Observation:
    """What the coordinator reads of ``rec`` (the equal of
    :func:`fleet.coordination.coordinator.observation_from_record`), from the ``pose`` and the
    ``view`` the record was made of: no record taken apart, no pose built again."""
    return make_observation(
        t=rec.t, pose=pose, battery=rec.battery, mode=view.mode, stuck=rec.stuck, task_id=view.task_id,
        laps=view.laps, charging=rec.charging, picks_done=view.picks_done, result_id=view.result_id,
        result=view.result, steps_done=view.steps_done,
    )  # fmt: skip


__all__ = ["TreeView", "observation", "status_changed"]
