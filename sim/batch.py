"""The simulator's batch reads, one path for all of them: :meth:`SimBatch.query_batch` (the
navigation contract's :class:`fleet.navigation.BatchNavigation`: many robots' states and goals in
one call) and the whole-fleet tables :meth:`SimBatch.goal_table` / :meth:`SimBatch.robot_table`
read the same state arrays (:class:`sim.state.FleetState`), not one snapshot object per robot
and goal.

A goal that is its robot's latest motion goal is answered from the status arrays (``g_num``,
``g_code``; a running planned navigation, ``g_nav``, takes its remaining distance from the
follower's arrays for all such rows at once); only finished goals, computations, older goals
and other running tasks read their record (a few rows per call in a patrolling fleet).

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
from sim import batch_kernels
from sim.dispatch import GoalDispatch
from sim.goals import TERMINAL
from sim.localization import Localization
from sim.snapshots import GoalTable, RobotTable
from sim.state import FleetState
from sim.tasks import NavigateTask

#: Goal ids remembered with their robot row and number (cleared when it holds more).
ID_CACHE = 65536
#: Batches of at least this many goals reuse the last call's rows (``SimBatch._goal_rows``).
_INCREMENTAL_MIN = 64


def _changed_positions(
    new: list[str | None], old: list[str | None], lo: int, hi: int, out: list[int]
) -> None:
    """Append to ``out``, in increasing order, the positions in ``lo .. hi - 1`` where
    ``new`` and ``old`` differ, by halving the range while its halves differ (a list
    comparison first compares the items' identities)."""
    if new[lo:hi] == old[lo:hi]:
        return
    if hi - lo <= 16:
        out.extend(k for k in range(lo, hi) if new[k] != old[k])
        return
    mid = (lo + hi) // 2
    _changed_positions(new, old, lo, mid, out)
    _changed_positions(new, old, mid, hi, out)


class SimBatch:
    """The simulator's batch reads (see the module docstring) over its state arrays, its
    localization, its goal dispatch and its per-robot ``robot_state`` (for rows that are not
    localized). One per simulator; pure reads."""

    def __init__(
        self,
        state: FleetState,
        localization: Localization,
        dispatch: GoalDispatch,
        robot_state: Callable[[str], RobotState],
        compiled: bool = False,
    ) -> None:
        self.state = state
        self.compiled = compiled
        self.localization = localization
        self.dispatch = dispatch
        self.robot_state = robot_state
        self._rows_of: tuple[list[str], npt.NDArray[np.intp]] = ([], np.zeros(0, dtype=np.intp))
        self._ids: dict[str | None, int] = {None: -1}
        #: the goal ids of the last call and their rows and numbers (``_goal_rows``)
        self._last_ids: list[str | None] = []
        self._last_rows: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        self._last_nums: npt.NDArray[np.int64] = np.zeros(0, dtype=np.int64)
        #: Robots (by row) whose navigation is down (the ``navigation_down`` fault), kept by
        #: ``Simulator.set_fault``.
        self.navigation_down: set[int] = set()

    def query_batch(self, namespaces: Sequence[str], goal_ids: Sequence[str | None]) -> NavBatch:
        """The batch of ``namespaces`` / ``goal_ids`` (see the module docstring). Raises
        :class:`BackendError` for an unknown namespace and ``ValueError`` when the sequences
        differ in length."""
        if len(namespaces) != len(goal_ids):
            raise ValueError(f"query_batch: {len(namespaces)} namespaces but {len(goal_ids)} goal ids")
        idx = self._rows(namespaces)
        s = self.state
        # the gathers are new arrays: no second copy (astype copy=False)
        x, y, th = (a[idx].astype(np.float64, copy=False) for a in (s.x, s.y, s.th))
        localized = self._localized()[idx]
        for k in np.flatnonzero(~localized).tolist():  # rare: the estimate, as robot_state reports it
            pose = self.robot_state(namespaces[k]).pose
            x[k], y[k], th[k] = (math.nan,) * 3 if pose is None else (pose.x, pose.y, pose.theta)
        status, error, remaining = self._goals(goal_ids)
        ready = np.ones(s.n, dtype=np.bool_)
        ready[list(self.navigation_down)] = False
        return NavBatch(
            namespaces=tuple(namespaces),
            goal_ids=tuple(goal_ids),
            x=x,
            y=y,
            theta=th,
            battery=s.battery[idx].astype(np.float64, copy=False),
            distance_m=s.dist[idx].astype(np.float64, copy=False),
            collisions=s.collisions[idx].astype(np.int64, copy=False),
            charging=s.charging[idx].astype(np.bool_, copy=False),
            stuck=s.stuck[idx].astype(np.bool_, copy=False),
            localized=localized,
            navigation_ready=ready[idx],
            goal_status=status,
            goal_error=error,
            distance_remaining=remaining,
        )

    def goal_table(self) -> GoalTable:
        """Every robot's latest motion goal number and status, in robot order (the rows
        :meth:`query_batch` answers from the arrays)."""
        n = self.state.n
        return GoalTable(self.state.g_num[:n].copy(), self.state.g_code[:n].astype(np.int8))

    def robot_table(self) -> RobotTable:
        """Every robot's true state, in robot order."""
        s, n = self.state, self.state.n
        x, y, th, v, w, bat, dist, ch, st, col = (
            a[:n].copy()
            for a in (s.x, s.y, s.th, s.v, s.w, s.battery, s.dist, s.charging, s.stuck, s.collisions)
        )
        return RobotTable(x, y, th, v, w, bat, dist, ch, st, col)

    def _rows(self, namespaces: Sequence[str]) -> npt.NDArray[np.intp]:
        """The state rows of ``namespaces`` (remembered for the last list asked for)."""
        known, idx = self._rows_of
        if len(known) == len(namespaces) and known == list(namespaces):
            return idx
        robots = self.dispatch.robots
        try:
            idx = np.fromiter((robots[ns].index for ns in namespaces), dtype=np.intp, count=len(namespaces))
        except KeyError as e:
            raise BackendError(f"no robot with namespace {e.args[0]!r} in the simulator") from None
        self._rows_of = (list(namespaces), idx)
        return idx

    def _localized(self) -> npt.NDArray[np.bool_]:
        """Whether each robot's localizer has a converged estimate and no loss fault."""
        ok = np.ones(len(self.localization.robots), dtype=np.bool_)
        ok[self.localization.unlocalized()] = False
        return ok

    def _goal_rows(
        self, goal_ids: Sequence[str | None]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.int64]]:
        """The robot row and the ``n`` of each goal id ``"<namespace>#<n>"``; row -1 for
        ``None`` and for an id that names no robot of this simulator. A poller asks for nearly
        the same ids every time (a few goals re-sent between two polls): the answer of the
        last call is kept and only the ids that changed are looked up again (found by
        comparing halves of the lists, which costs a pointer comparison per id)."""
        ids = list(goal_ids) if not isinstance(goal_ids, list) else goal_ids
        last = self._last_ids
        if len(last) == len(ids) and len(ids) >= _INCREMENTAL_MIN:
            if ids == last:
                return self._last_rows, self._last_nums
            changed: list[int] = []
            _changed_positions(ids, last, 0, len(ids), changed)
            if len(changed) <= len(ids) // 8:
                if changed:
                    code = self._codes([ids[k] for k in changed])
                    at = np.array(changed, dtype=np.intp)
                    self._last_rows[at] = np.where(code < 0, -1, code >> 32)
                    self._last_nums[at] = code & 0xFFFFFFFF
                    for k in changed:
                        last[k] = ids[k]
                return self._last_rows, self._last_nums
        code = self._codes(ids)
        rows = np.where(code < 0, -1, code >> 32).astype(np.intp)
        nums = code & 0xFFFFFFFF
        self._last_ids, self._last_rows, self._last_nums = list(ids), rows, nums
        return rows, nums

    def _codes(self, goal_ids: list[str | None]) -> npt.NDArray[np.int64]:
        """Each goal id as ``row << 32 | n`` (-1: no robot), remembered by id."""
        ids = self._ids
        get = ids.get
        keys = list(map(get, goal_ids))
        if None in keys:
            if len(ids) >= ID_CACHE:
                ids.clear()
                ids[None] = -1
            robots = self.dispatch.robots
            for k in [k for k, key in enumerate(keys) if key is None]:
                gid = goal_ids[k]
                assert gid is not None
                ns, _, num = gid.rpartition("#")
                robot = robots.get(ns)
                ok = robot is not None and num.isdigit() and 0 < int(num) < 1 << 32
                ids[gid] = keys[k] = (robot.index << 32 | int(num)) if ok and robot is not None else -1
        return np.fromiter(keys, dtype=np.int64, count=len(keys))

    def _goals(
        self, goal_ids: Sequence[str | None]
    ) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.int32], npt.NDArray[np.float64]]:
        """Status codes, error codes and remaining distances of ``goal_ids``."""
        n = len(goal_ids)
        status = np.full(n, NO_GOAL, dtype=np.int8)
        error = np.zeros(n, dtype=np.int32)
        remaining = np.full(n, math.nan, dtype=np.float64)
        rows, nums = self._goal_rows(goal_ids)
        s = self.state
        if self.compiled:
            slow = np.empty(n, dtype=np.int64)
            k_slow = batch_kernels.goal_rows(
                rows, nums, s.g_num, s.g_code, s.g_nav, TERMINAL, s.x, s.y, s.f_t,
                s.c_ax, s.c_ay, s.c_bx, s.c_by, s.c_suf, s.f_xy, s.f_len, status, remaining, slow,
            )  # fmt: skip
            for k in slow[:k_slow].tolist():
                gid = goal_ids[k]
                assert gid is not None
                status[k], error[k], remaining[k] = self._slow_goal(gid)
            return status, error, remaining
        safe = np.maximum(rows, 0)
        latest = (rows >= 0) & (s.g_num[safe] == nums) & (nums > 0)
        code = s.g_code[safe]
        fast = latest & s.g_nav[safe] & ~TERMINAL[code]
        k_fast = np.flatnonzero(fast)
        status[k_fast] = code[k_fast]
        remaining[k_fast] = _path_remaining(s, safe[k_fast])
        for k in np.flatnonzero(~fast & (rows >= 0)).tolist():
            gid = goal_ids[k]
            assert gid is not None
            status[k], error[k], remaining[k] = self._slow_goal(gid)
        return status, error, remaining

    def _slow_goal(self, gid: str) -> tuple[int, int, float]:
        """Status code, error code and remaining distance of one goal from its record."""
        dispatch = self.dispatch
        try:
            record = dispatch.goals.get(gid)
        except KeyError:
            return NO_GOAL, 0, math.nan
        fb = record.feedback
        if not record.terminal:
            i = dispatch.robots[record.namespace].index
            task = dispatch.tasks.get(i)
            if task is not None and task.record is record:
                if isinstance(task, NavigateTask):
                    rem = 0.0
                    if task.planned:
                        rem = float(_path_remaining(self.state, np.array([i], dtype=np.intp))[0])
                    return GOAL_CODES[record.status], record.error_code, rem
                fb = task.feedback()
        rem = math.nan if fb.distance_remaining_m is None else fb.distance_remaining_m
        return GOAL_CODES[record.status], record.error_code, rem


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
