"""The simulator's batch query (:class:`fleet.navigation.BatchNavigation`): many robots' states
and goals in one call, read from the simulator's arrays instead of one snapshot object per
robot and goal.

Rows agree with :meth:`sim.simulator.Simulator.robot_state` and ``goal_state``: the pose is the
true pose of a localized robot (a robot that is not localized reports its estimate, read
through ``robot_state``); ``distance_remaining`` of a navigation goal is the path length the
follower has left (:meth:`sim.state.FleetState.progress`, computed for all rows at once), of
other running goals their task's feedback, of a finished goal its stored feedback.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from fleet.errors import BackendError
from fleet.navigation import GOAL_CODES, NO_GOAL, NavBatch
from fleet.types import RobotState
from sim.dispatch import GoalDispatch
from sim.localization import Localization
from sim.state import FleetState
from sim.tasks import NavigateTask


class SimBatch:
    """The simulator's :class:`~fleet.navigation.BatchNavigation` over its state arrays, its
    localization, its goal dispatch and its per-robot ``robot_state`` (for rows that are not
    localized)."""

    def __init__(
        self,
        state: FleetState,
        localization: Localization,
        dispatch: GoalDispatch,
        robot_state: Callable[[str], RobotState],
    ) -> None:
        self.state = state
        self.localization = localization
        self.dispatch = dispatch
        self.robot_state = robot_state

    def query_batch(self, namespaces: Sequence[str], goal_ids: Sequence[str | None]) -> NavBatch:
        """The batch of ``namespaces`` / ``goal_ids`` (see the module docstring). Raises
        :class:`BackendError` for an unknown namespace and ``ValueError`` when the sequences
        differ in length."""
        return query_batch(self, namespaces, goal_ids)


def query_batch(sim: SimBatch, namespaces: Sequence[str], goal_ids: Sequence[str | None]) -> NavBatch:
    """The :class:`~fleet.navigation.NavBatch` of ``namespaces`` / ``goal_ids`` in ``sim``."""
    if len(namespaces) != len(goal_ids):
        raise ValueError(f"query_batch: {len(namespaces)} namespaces but {len(goal_ids)} goal ids")
    robots = sim.dispatch.robots
    try:
        rows = [robots[ns] for ns in namespaces]
    except KeyError as e:
        raise BackendError(f"no robot with namespace {e.args[0]!r} in the simulator") from None
    idx = np.fromiter((r.index for r in rows), dtype=np.intp, count=len(rows))
    s = sim.state
    x, y, th = s.x[idx].astype(np.float64), s.y[idx].astype(np.float64), s.th[idx].astype(np.float64)
    est = sim.localization.robots
    localized = np.array([est[r.index].localized and not est[r.index].lost for r in rows], dtype=np.bool_)
    for k in np.flatnonzero(~localized).tolist():  # rare: the estimate, as robot_state reports it
        pose = sim.robot_state(namespaces[k]).pose
        x[k], y[k], th[k] = (math.nan,) * 3 if pose is None else (pose.x, pose.y, pose.theta)
    status, error, remaining, nav = _goals(sim, goal_ids)
    if nav:
        rows_nav = np.array(nav, dtype=np.intp)
        remaining[rows_nav] = _path_remaining(sim.state, idx[rows_nav])
    return NavBatch(
        namespaces=tuple(namespaces),
        goal_ids=tuple(goal_ids),
        x=x,
        y=y,
        theta=th,
        battery=s.battery[idx].astype(np.float64),
        distance_m=s.dist[idx].astype(np.float64),
        collisions=s.collisions[idx].astype(np.int64),
        charging=s.charging[idx].astype(np.bool_),
        stuck=s.stuck[idx].astype(np.bool_),
        localized=localized,
        navigation_ready=np.array([r.fault != "navigation_down" for r in rows], dtype=np.bool_),
        goal_status=status,
        goal_error=error,
        distance_remaining=remaining,
    )


def _goals(
    sim: SimBatch, goal_ids: Sequence[str | None]
) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.int32], npt.NDArray[np.float64], list[int]]:
    """Status codes, error codes and remaining distances of ``goal_ids``; the rows whose goal is
    a planned navigation task running now (their distance is filled in from the arrays)."""
    n = len(goal_ids)
    status = np.full(n, NO_GOAL, dtype=np.int8)
    error = np.zeros(n, dtype=np.int32)
    remaining = np.full(n, math.nan, dtype=np.float64)
    dispatch = sim.dispatch
    book, tasks, robots = dispatch.goals, dispatch.tasks, dispatch.robots
    nav: list[int] = []
    for k, gid in enumerate(goal_ids):
        if gid is None:
            continue
        try:
            record = book.get(gid)
        except KeyError:
            continue
        status[k] = GOAL_CODES[record.status]
        error[k] = record.error_code
        fb = record.feedback
        if not record.terminal:
            task = tasks.get(robots[record.namespace].index)
            if task is not None and task.record is record:
                if isinstance(task, NavigateTask):
                    if task.planned:
                        nav.append(k)
                        continue
                    remaining[k] = 0.0
                    continue
                fb = task.feedback()
        if fb.distance_remaining_m is not None:
            remaining[k] = fb.distance_remaining_m
    return status, error, remaining, nav


def _path_remaining(s: FleetState, idx: npt.NDArray[np.intp]) -> npt.NDArray[np.float64]:
    """:meth:`sim.state.FleetState.remaining` of robots ``idx``, for all of them at once."""
    x, y = s.x[idx], s.y[idx]
    t = s.f_t[idx]
    ax, ay, bx, by = s.c_ax[idx], s.c_ay[idx], s.c_bx[idx], s.c_by[idx]
    qx, qy = ax + t * (bx - ax), ay + t * (by - ay)
    rem = np.hypot(bx - qx, by - qy) + s.c_suf[idx] + np.hypot(qx - x, qy - y)
    rem[s.f_xy[idx] | (s.f_len[idx] < 2)] = 0.0
    out: npt.NDArray[np.float64] = rem.astype(np.float64)
    return out
