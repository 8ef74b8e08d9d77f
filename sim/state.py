"""The simulator's state as NumPy arrays: one row per robot, one flat buffer of path points.

:class:`FleetState` holds every per-robot quantity the step updates (pose, velocities,
battery, odometer, flags, progress checker, path-follower cursor) in arrays of length
``capacity`` (the first ``n`` rows are robots, in the order they were added), so
:meth:`sim.simulator.Simulator.step` moves all robots with array operations. Paths being
followed live in one flat buffer of points (``px``/``py``) with, per point, the length of the
segment starting there (``seg_len``) and the path length from there to the path's end
(``suffix``); robot ``i`` follows points ``f_off[i] .. f_off[i] + f_len[i] - 1``. The indices of
the poses to pass (vias) live in a second flat buffer. Units meters, radians, seconds; frame
``map``.

The follower's per-step arithmetic reads a per-robot cache of what it needs from those
buffers (``c_*``: the current segment's end points ``c_ax .. c_by``, its vector ``c_ex``,
``c_ey``, ``c_den = max(length**2, 1e-18)``, ``c_long = length > 1e-9``, the path length after
it ``c_suf``; the next via's point ``c_vx``, ``c_vy``, its point index ``c_vseg`` and
``c_vmore``, whether a via other than the last is still to pass; the path's last point ``c_gx``,
``c_gy``). The values are the same floats the buffers give; :meth:`FleetState.load_segments`
and :meth:`FleetState.load_vias` refresh them whenever ``f_seg`` / ``f_nv`` change.

The robot's latest motion goal is ``g_num`` (the ``n`` of its id ``"<namespace>#<n>"``, 0:
none yet) with status ``g_code`` (a code of :data:`sim.goals.STATUS_CODES`, -1: none), kept
by :class:`sim.dispatch.GoalDispatch` for batch polling; ``g_nav`` tells that this goal is running
as a planned navigation task (NavigateToPose, NavigateThroughPoses, FollowPath) on the path
follower, so its remaining distance is the follower's (:mod:`sim.batch` reads it from the arrays).

Snapshots (goal feedback, robot state) read one robot at a time through :meth:`FleetState.row`.
Between steps every robot's row is copied out of the arrays at once, on the first read after
a change of the whole fleet (``version`` counts the changes: the simulator's step,
:meth:`FleetState.add`); a change of one robot between steps (:meth:`FleetState.attach`,
:meth:`FleetState.detach`, the :class:`sim.robot.Robot` setters: :meth:`FleetState.touch`)
refreshes only that robot's row on its next read, so a goal sent does not cost a copy of the
whole fleet. While a step runs (``busy``) rows are read from the arrays directly.
"""

from __future__ import annotations

import math

import numpy as np

_FLOAT = (
    "x y th v w battery dist px py pt f_t f_yaw f_best f_btime vd wd "
    "c_ax c_ay c_bx c_by c_ex c_ey c_den c_suf c_vx c_vy c_gx c_gy"
).split()
_INT = (
    "collisions",
    "f_seg",
    "f_off",
    "f_len",
    "f_voff",
    "f_vn",
    "f_nv",
    "f_side",
    "c_vseg",
    "g_num",
    "g_code",
)
_BOOL = (
    "charging",
    "stuck",
    "stalled",
    "halt",
    "has_task",
    "drives",
    "fol",
    "f_xy",
    "c_long",
    "c_vmore",
    "g_nav",
)
#: The arrays of a :meth:`FleetState.row`, in order.
ROW = (
    "x y th v w battery charging stuck dist collisions f_t c_ax c_ay c_bx c_by c_suf f_xy f_len f_nv f_vn"
).split()


class FleetState:
    """Per-robot arrays (see the module docstring). Grows by doubling."""

    def __init__(self, capacity: int = 16) -> None:
        self.n = 0
        self.capacity = capacity
        for name in _FLOAT:
            setattr(self, name, np.zeros(capacity))
        for name in _INT:
            setattr(self, name, np.zeros(capacity, dtype=np.int64))
        for name in _BOOL:
            setattr(self, name, np.zeros(capacity, dtype=bool))
        self.pts_x = np.zeros(1024)
        self.pts_y = np.zeros(1024)
        self.seg_len = np.zeros(1024)
        self.suffix = np.zeros(1024)
        self.n_pts = 0
        self.vias = np.zeros(256, dtype=np.int64)
        self.n_vias = 0
        self.version = 0
        self.busy = False
        self._rows = np.zeros((0, len(ROW)))
        self._rows_version = -1
        #: rows of the copy that are stale (changed by :meth:`touch` since it was made)
        self._dirty: set[int] = set()

    # typed views for mypy (set dynamically above)
    x: np.ndarray
    y: np.ndarray
    th: np.ndarray
    v: np.ndarray
    w: np.ndarray
    battery: np.ndarray
    dist: np.ndarray
    px: np.ndarray
    py: np.ndarray
    pt: np.ndarray
    f_t: np.ndarray
    f_yaw: np.ndarray
    f_best: np.ndarray
    f_btime: np.ndarray
    vd: np.ndarray
    wd: np.ndarray
    collisions: np.ndarray
    f_seg: np.ndarray
    f_off: np.ndarray
    f_len: np.ndarray
    f_voff: np.ndarray
    f_vn: np.ndarray
    f_nv: np.ndarray
    f_side: np.ndarray
    c_ax: np.ndarray
    c_ay: np.ndarray
    c_bx: np.ndarray
    c_by: np.ndarray
    c_ex: np.ndarray
    c_ey: np.ndarray
    c_den: np.ndarray
    c_suf: np.ndarray
    c_vx: np.ndarray
    c_vy: np.ndarray
    c_gx: np.ndarray
    c_gy: np.ndarray
    c_vseg: np.ndarray
    g_num: np.ndarray
    g_code: np.ndarray
    g_nav: np.ndarray
    c_long: np.ndarray
    c_vmore: np.ndarray
    charging: np.ndarray
    stuck: np.ndarray
    stalled: np.ndarray
    halt: np.ndarray
    has_task: np.ndarray
    drives: np.ndarray
    fol: np.ndarray
    f_xy: np.ndarray

    def add(self, x: float, y: float, theta: float, battery: float, now: float) -> int:
        """Append a robot row at rest; return its index."""
        if self.n == self.capacity:
            self.capacity *= 2
            for name in (*_FLOAT, *_INT, *_BOOL):
                old = getattr(self, name)
                new = np.zeros(self.capacity, dtype=old.dtype)
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
        i = self.n
        self.n += 1
        self.version += 1
        self.x[i], self.y[i], self.th[i] = x, y, theta
        self.battery[i] = battery
        self.px[i], self.py[i], self.pt[i] = x, y, now
        self.g_code[i] = -1
        return i

    # -- paths --------------------------------------------------------------------------

    def attach(
        self, i: int, path: list[tuple[float, float]], vias: list[int], final_yaw: float, now: float
    ) -> None:
        """Make robot ``i`` follow ``path`` (at least 2 points) through ``vias``."""
        self.touch(i)
        k = len(path)
        self._reserve_points(k)
        self._reserve_vias(len(vias))
        o = self.n_pts
        xs = np.array([p[0] for p in path], dtype=float)
        ys = np.array([p[1] for p in path], dtype=float)
        seg = np.zeros(k)
        seg[:-1] = np.hypot(np.diff(xs), np.diff(ys))
        # Python-float suffix sums, accumulated from the end as the scalar follower did
        suf = [0.0] * k
        sl = seg.tolist()
        for j in range(k - 2, -1, -1):
            suf[j] = suf[j + 1] + sl[j]
        self.pts_x[o : o + k] = xs
        self.pts_y[o : o + k] = ys
        self.seg_len[o : o + k] = seg
        self.suffix[o : o + k] = suf
        self.n_pts += k
        vo = self.n_vias
        self.vias[vo : vo + len(vias)] = vias
        self.n_vias += len(vias)
        self.fol[i] = True
        self.f_off[i], self.f_len[i], self.f_seg[i], self.f_t[i] = o, k, 0, 0.0
        self.f_voff[i], self.f_vn[i], self.f_nv[i] = vo, len(vias), 0
        self.f_xy[i] = False
        self.f_side[i] = 0
        self.f_yaw[i] = final_yaw
        self.f_best[i] = math.inf
        self.f_btime[i] = now
        self.c_gx[i], self.c_gy[i] = xs[-1], ys[-1]
        one = np.array([i], dtype=np.int64)
        self.load_segments(one)
        self.load_vias(one)

    def load_segments(self, idx: np.ndarray) -> None:
        """Refresh the cached current-segment geometry (``c_ax`` .. ``c_suf``) of robots
        ``idx`` (an index array) from ``f_off`` / ``f_seg`` and the point buffers."""
        k = self.f_off[idx] + self.f_seg[idx]
        ax, ay = self.pts_x[k], self.pts_y[k]
        bx, by = self.pts_x[k + 1], self.pts_y[k + 1]
        length = self.seg_len[k]
        self.c_ax[idx], self.c_ay[idx], self.c_bx[idx], self.c_by[idx] = ax, ay, bx, by
        self.c_ex[idx] = bx - ax
        self.c_ey[idx] = by - ay
        self.c_den[idx] = np.maximum(length * length, 1e-18)
        self.c_long[idx] = length > 1e-9
        self.c_suf[idx] = self.suffix[k + 1]

    def load_vias(self, idx: np.ndarray) -> None:
        """Refresh the cached next via (``c_vx``, ``c_vy``, ``c_vseg``, ``c_vmore``) of robots
        ``idx`` from ``f_voff`` / ``f_nv`` / ``f_vn`` and the via buffer."""
        vn = self.f_vn[idx]
        nv = self.f_nv[idx]
        vi = self.vias[self.f_voff[idx] + np.minimum(nv, vn - 1)]
        k = self.f_off[idx] + vi
        self.c_vseg[idx] = vi
        self.c_vx[idx] = self.pts_x[k]
        self.c_vy[idx] = self.pts_y[k]
        self.c_vmore[idx] = nv < vn - 1

    def detach(self, i: int) -> None:
        self.touch(i)
        self.fol[i] = False

    def touch(self, i: int) -> None:
        """Robot ``i``'s values change (only its row): counts as a change of ``version``;
        between steps the copy of the rows stays valid for every other robot."""
        if self._rows_version == self.version and not self.busy:
            self._dirty.add(i)
            self._rows_version += 1
        self.version += 1

    def row(self, i: int) -> list[float]:
        """Robot ``i``'s values of the :data:`ROW` arrays, as Python floats (flags as 0.0 /
        1.0, counts as whole numbers): the same values ``.item(i)`` gives. Between steps the
        rows of all robots are copied out once after a change of the whole fleet, and a row
        :meth:`touch` made stale is copied again alone; during a step they are read from the
        arrays."""
        if self._rows_version != self.version:
            if self.busy:
                return [float(getattr(self, name).item(i)) for name in ROW]
            n = self.n
            self._rows = np.column_stack([getattr(self, name)[:n] for name in ROW]).astype(float, copy=False)
            self._rows_version = self.version
            self._dirty.clear()
        elif self._dirty and i in self._dirty:
            self._dirty.discard(i)
            self._rows[i] = [getattr(self, name).item(i) for name in ROW]
        return self._rows[i].tolist()  # type: ignore[no-any-return]

    def progress(self, i: int) -> tuple[float, float, float, float, int]:
        """``(x, y, theta, remaining, poses_left)`` of robot ``i``: its pose, the path length
        (m) from its projection on its path to the end plus its distance to the projection,
        and the poses of the path not passed yet; 0 and 0 once the final position was
        reached (or without a path)."""
        x, y, th, _, _, _, _, _, _, _, t, ax, ay, bx, by, suf, xy, ln, nv, vn = self.row(i)
        if xy:
            return x, y, th, 0.0, 0
        left = int(vn - nv)
        if ln < 2.0:
            return x, y, th, 0.0, left
        qx, qy = ax + t * (bx - ax), ay + t * (by - ay)
        return x, y, th, math.hypot(bx - qx, by - qy) + suf + math.hypot(qx - x, qy - y), left

    def remaining(self, i: int) -> float:
        """Path length (m) from robot ``i``'s projection on its path to the end, plus its
        distance to the projection; 0 once the final position was reached."""
        return self.progress(i)[3]

    def poses_left(self, i: int) -> int:
        return self.progress(i)[4]

    def _live(self) -> np.ndarray:
        return np.flatnonzero(self.fol[: self.n])

    def _reserve_points(self, k: int) -> None:
        if self.n_pts + k <= self.pts_x.shape[0]:
            return
        live = self._live()
        used = int(self.f_len[live].sum())
        cap = self.pts_x.shape[0]
        while used + k > cap // 2:
            cap *= 2
        nx, ny, ns, nf = np.zeros(cap), np.zeros(cap), np.zeros(cap), np.zeros(cap)
        o = 0
        for i in live.tolist():
            a, ln = int(self.f_off[i]), int(self.f_len[i])
            nx[o : o + ln] = self.pts_x[a : a + ln]
            ny[o : o + ln] = self.pts_y[a : a + ln]
            ns[o : o + ln] = self.seg_len[a : a + ln]
            nf[o : o + ln] = self.suffix[a : a + ln]
            self.f_off[i] = o
            o += ln
        self.pts_x, self.pts_y, self.seg_len, self.suffix, self.n_pts = nx, ny, ns, nf, o

    def _reserve_vias(self, k: int) -> None:
        if self.n_vias + k <= self.vias.shape[0]:
            return
        live = self._live()
        used = int(self.f_vn[live].sum())
        cap = self.vias.shape[0]
        while used + k > cap // 2:
            cap *= 2
        nv = np.zeros(cap, dtype=np.int64)
        o = 0
        for i in live.tolist():
            a, ln = int(self.f_voff[i]), int(self.f_vn[i])
            nv[o : o + ln] = self.vias[a : a + ln]
            self.f_voff[i] = o
            o += ln
        self.vias, self.n_vias = nv, o
