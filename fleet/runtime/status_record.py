"""An agent's status record: the fields its tree gives (:class:`TreeView`), whether a new
record says something the last one published did not (:func:`status_changed`, for publishing
on change), and what an in-process coordinator reads of it (:func:`observation`,
:func:`observation_of`)."""

from __future__ import annotations

import math
from typing import NamedTuple

from py_trees.blackboard import Blackboard

from fleet.coordination.views import Observation, make_observation
from fleet.diagnostics import Diagnostic, HealthParams, Level, problems, robot_diagnostics, worst
from fleet.messages import StatusRecord
from fleet.types import Pose2D, RobotState
from nodes.blackboard import key_path


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


#: The blackboard keys :func:`tree_view` reads, in its order.
VIEW_KEYS = (
    "task_id", "active_leaf", "mode", "laps", "lap_task_id", "route_progress", "picks_done", "result_id",
    "result", "step_index", "steps_task_id",
)  # fmt: skip


def view_names(namespace: str) -> tuple[str, ...]:
    """The absolute blackboard names of :data:`VIEW_KEYS` of robot ``namespace``."""
    return tuple(key_path(namespace, k) for k in VIEW_KEYS)


def tree_view(bt: str, names: tuple[str, ...]) -> TreeView:
    """What a status record reports of a tree whose root's status is named ``bt`` and of its
    robot's blackboard (``names``: :func:`view_names`), read now: the values a blackboard
    client of the robot reads (the agent's has every key and no remapping), taken from the
    store directly (a client's read checks its access and resolves the name each time).
    Raises ``KeyError`` for a key never written, as the client does."""
    store = Blackboard.storage
    task_id, leaf, mode, laps, lap_task, progress, picks, result_id, result, step, steps_task = [
        store[n] for n in names
    ]
    return TreeView(
        bt, str(leaf or ""), str(mode), task_id, int(laps) if lap_task is not None and lap_task == task_id else 0,
        float(progress or 0.0), int(picks or 0), result_id, str(result or ""),
        int(step) if steps_task is not None and steps_task == task_id else 0,
    )  # fmt: skip


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


def held_changed(old: Held, new: Held, params: HealthParams) -> bool:
    """``status_changed(status_record(n, ns, old, params), status_record(n, ns, new, params))``
    decided from the held values, without building either record: the agent's test, each
    period after the status period, of whether its record says something the last one
    published did not. A tree view that is the same object (a period without a tree tick
    reuses its view) is not compared field by field."""
    ost, ov, _, _, oack, ogrant, omal, orej, owhy, owait = old
    nst, nv, _, _, nack, ngrant, nmal, nrej, nwhy, nwait = new
    p, q = ost.pose, nst.pose
    if (p is None) != (q is None):
        return True
    if p is not None and q is not None:
        if abs(p.x - q.x) > POSE_EPS_M or abs(p.y - q.y) > POSE_EPS_M:
            return True
        if abs(math.remainder(p.theta - q.theta, math.tau)) > THETA_EPS_RAD:
            return True
    if (
        abs(float(ost.battery) - float(nst.battery)) > BATTERY_EPS
        or abs(float(ost.distance_m) - float(nst.distance_m)) > POSE_EPS_M
        or bool(ost.charging) != bool(nst.charging)
        or bool(ost.stuck) != bool(nst.stuck)
        or int(ost.collisions) != int(nst.collisions)
        or oack != nack
        or ogrant != ngrant
        or omal != nmal
        or orej != nrej
    ):
        return True
    if ov is not nv and (
        abs(ov.progress - nv.progress) > PROGRESS_EPS
        or ov.mode != nv.mode
        or ov.task_id != nv.task_id
        or ov.bt != nv.bt
        or ov.leaf != nv.leaf
        or ov.laps != nv.laps
        or ov.picks_done != nv.picks_done
        or ov.result_id != nv.result_id
        or ov.result != nv.result
        or ov.steps_done != nv.steps_done
    ):
        return True
    return diagnostics(ost, params, owhy, owait) != diagnostics(nst, params, nwhy, nwait)


def observation(rec: StatusRecord, pose: Pose2D | None, view: TreeView) -> Observation:
    """What the coordinator reads of ``rec`` (the equal of
    :func:`fleet.coordination.coordinator.observation_from_record`), from the ``pose`` and the
    ``view`` the record was made of: no record taken apart, no pose built again."""
    return make_observation(
        t=rec.t, pose=pose, battery=rec.battery, mode=view.mode, stuck=rec.stuck, task_id=view.task_id,
        laps=view.laps, charging=rec.charging, picks_done=view.picks_done, result_id=view.result_id,
        result=view.result, steps_done=view.steps_done,
    )  # fmt: skip


#: What a period's status record is built from (:func:`status_record`): the robot state, the
#: tree view, ``t``, ``seq``, the order ack ``(epoch, seq)``, ``grant_seq``, ``malformed``,
#: ``rejected``, the safety watchdog's reason, whether the robot waits for its first state.
Held = tuple[RobotState, TreeView, float, int, tuple[int, int], int, int, int, str, bool]


def status_record(name: str, namespace: str, held: Held, params: HealthParams) -> StatusRecord:
    """The status record of robot ``name`` (``namespace``) of the values ``held`` at a period,
    its diagnostics judged by ``params`` (a pure function of them)."""
    st, v, t, seq, ack, grant_seq, malformed, rejected, reason, waiting = held
    health, diag = diagnostics(st, params, reason, waiting)
    pose = st.pose.as_tuple() if st.pose is not None else None
    return StatusRecord(
        robot=name, ns=namespace, t=t, pose=pose, battery=float(st.battery), charging=bool(st.charging),
        stuck=bool(st.stuck), bt=v.bt, leaf=v.leaf, mode=v.mode, task_id=v.task_id, laps=v.laps,
        progress=v.progress, distance_m=float(st.distance_m), collisions=int(st.collisions), seq=seq,
        picks_done=v.picks_done, health=health, diag=diag, result_id=v.result_id, result=v.result,
        steps_done=v.steps_done, epoch=ack[0], order_seq=ack[1], grant_seq=grant_seq, malformed=malformed,
        rejected=rejected,
    )  # fmt: skip


def diagnostics(
    st: RobotState, h: HealthParams, why: str, waiting: bool
) -> tuple[int, tuple[tuple[str, int, str], ...]]:
    """``(worst level, the checks that are not OK)`` of ``st`` judged by ``h``, the safety
    watchdog's reason ``why`` and whether the robot is ``waiting`` for its first state; a
    healthy robot (the common case) costs no check objects."""
    if waiting:
        return int(Level.WARN), (("localization", int(Level.WARN), "waiting for the robot's first state"),)
    if (
        st.localized
        and st.navigation_ready
        and st.battery_known
        and not st.stuck
        and not st.safety_stop
        and st.pose is not None
        and st.battery >= h.battery_low
        and st.pose_age_s <= 0.5 * h.localization_timeout_s
    ):
        return 0, ()
    items = robot_diagnostics(st, h)
    if why and not st.safety_stop:
        motion = Diagnostic("motion", Level.ERROR, f"safety stop: {why}")
        items = (*(d for d in items if d.name != "motion"), motion)
    return int(worst(items)), problems(items)


_new = object.__new__


def observation_of(
    t: float, pose: Pose2D | None, battery: float, stuck: bool, charging: bool, view: TreeView
) -> Observation:
    """:func:`observation` of the record an agent would build at ``t`` from a state with
    ``pose``, ``battery``, ``stuck`` and ``charging`` and the tree ``view``, built without the
    record (an agent builds a record only in the periods it publishes) and from positional
    values: the very instance ``Observation(...)`` builds (same class, same attribute dict in
    field order), for every robot every period."""
    obj = _new(Observation)
    obj.__dict__.update(
        t=t, pose=pose, battery=battery, mode=view.mode, stuck=stuck, task_id=view.task_id, laps=view.laps,
        charging=charging, picks_done=view.picks_done, result_id=view.result_id, result=view.result,
        steps_done=view.steps_done,
    )  # fmt: skip
    return obj


__all__ = [
    "Held",
    "held_changed",
    "TreeView",
    "diagnostics",
    "observation",
    "observation_of",
    "status_changed",
    "status_record",
]
