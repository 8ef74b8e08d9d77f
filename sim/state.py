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
"""

from __future__ import annotations

import math

import numpy as np

_FLOAT = ("x y th v w battery dist px py pt f_t f_yaw f_best f_btime vd wd").split()
_INT = ("collisions", "f_seg", "f_off", "f_len", "f_voff", "f_vn", "f_nv", "f_side")
_BOOL = ("charging", "stuck", "stalled", "has_task", "drives", "fol", "f_xy")


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
    charging: np.ndarray
    stuck: np.ndarray
    stalled: np.ndarray
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
        self.x[i], self.y[i], self.th[i] = x, y, theta
        self.battery[i] = battery
        self.px[i], self.py[i], self.pt[i] = x, y, now
        return i

    # -- paths --------------------------------------------------------------------------

    def attach(
        self, i: int, path: list[tuple[float, float]], vias: list[int], final_yaw: float, now: float
    ) -> None:
        """Make robot ``i`` follow ``path`` (at least 2 points) through ``vias``."""
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

    def detach(self, i: int) -> None:
        self.fol[i] = False

    def remaining(self, i: int) -> float:
        """Path length (m) from robot ``i``'s projection on its path to the end, plus its
        distance to the projection; 0 once the final position was reached."""
        if self.f_xy.item(i) or self.f_len.item(i) < 2:
            return 0.0
        k = self.f_off.item(i) + self.f_seg.item(i)
        px, py = self.pts_x, self.pts_y
        ax, ay, bx, by = px.item(k), py.item(k), px.item(k + 1), py.item(k + 1)
        t = self.f_t.item(i)
        qx, qy = ax + t * (bx - ax), ay + t * (by - ay)
        x, y = self.x.item(i), self.y.item(i)
        return math.hypot(bx - qx, by - qy) + self.suffix.item(k + 1) + math.hypot(qx - x, qy - y)

    def poses_left(self, i: int) -> int:
        return 0 if self.f_xy.item(i) else self.f_vn.item(i) - self.f_nv.item(i)

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
