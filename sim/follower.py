"""The vectorized path follower: the ``(v, w)`` command of every robot following a path.

Each step :meth:`PathFollower.follow` moves, for all path-following robots at once, each
robot's cursor along its path (:class:`sim.state.FleetState` ``f_seg``: the next segment once
the projection passes the segment's end or the robot comes within ``goal_tolerance`` of it, so
sharp turns cannot make the robot orbit a corner), passes the vias (intermediate poses) it
reached, detects arrival (every via passed, within ``goal_tolerance`` of the last point, then
within ``yaw_tolerance`` of the final yaw), picks a lookahead point ``0.3 + 0.3 |v|`` m ahead
on the path, detours around robots and dynamic obstacles (:mod:`sim.avoidance`) and turns that
into a turn-then-drive command. A robot whose remaining path has not shrunk by
:data:`APPROACH_M` within ``APPROACH_FACTOR * stuck_time_s`` stops too. The follower writes
the commands to ``vd`` / ``wd`` and returns the robots that stopped (arrived or no approach);
the goal dispatch tells their tasks.

Loops that advance a cursor (segment, via, lookahead) run their later rounds only over the
robots that advanced. Units m, rad, s; frame ``map``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fleet.robots import SimParams
from sim import detour_kernels, follower_kernels, kernels
from sim.avoidance import (
    AVOID_CLEAR_M,
    AVOID_LOOKAHEAD_M,
    COS_OFFSETS,
    FIRST_FREE,
    OFFSET_BITS,
    OFFSETS,
    SIN_OFFSETS,
    Avoidance,
)
from sim.state import FleetState

#: Heading error (rad) above which a path-following robot stops and rotates in place.
ROTATE_IN_PLACE_RAD = 0.8
#: Gain of the heading controller while driving (rad/s per rad of error).
HEADING_GAIN = 2.5
#: A path follower must shorten its remaining path by this much (m) ...
APPROACH_M = 0.1
#: ... at least once every ``APPROACH_FACTOR * stuck_time_s`` seconds, or its goal fails to
#: make progress.
APPROACH_FACTOR = 2.0

_NO_ROBOTS = np.zeros(0, dtype=np.int64)
_NO_FLAGS = np.zeros(0, dtype=bool)

#: ``(ax, ay, bx, by, ex, ey)``: each robot's current segment, its end points and its vector.
_Geometry = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
_Gather = Callable[[np.ndarray], np.ndarray]


class PathFollower:
    """Follows the paths attached in ``state`` (see the module docstring), detouring with
    ``avoidance``. ``compiled`` (default :func:`sim.kernels.enabled`): run the per-robot
    arithmetic as the compiled loops of :mod:`sim.follower_kernels`, else as NumPy array
    passes; both give the same bits."""

    def __init__(
        self, state: FleetState, params: SimParams, avoidance: Avoidance, compiled: bool | None = None
    ) -> None:
        self.state = state
        self.params = params
        self.avoidance = avoidance
        self.compiled = kernels.enabled() if compiled is None else compiled and kernels.ready()
        self._scratch = np.zeros((3, 0))
        self._rows = np.zeros(0, dtype=np.int64)

    def follow(self, F: np.ndarray, now: float, obst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Command every robot in ``F`` (increasing indices) at time ``now`` (s), with the
        dynamic obstacles ``obst`` (rows ``(x, y, radius)``). Returns ``(robots, arrived)``:
        the robots that stopped this step, in increasing order, and for each whether it
        arrived (else its remaining path stopped shrinking)."""
        if self.compiled:
            return self._follow_compiled(F, now, obst)
        s = self.state
        n = s.n
        full = F.size == n

        def get(arr: np.ndarray) -> np.ndarray:
            return arr[:n] if full else arr[F]

        X, Y = get(s.x), get(s.y)
        xy = get(s.f_xy).copy()
        act = ~xy
        seg, last, t, geo = self._advance_segments(F, get, full, X, Y, act)
        proj = np.minimum(np.maximum(t, 0.0), 1.0)
        nv = self._pass_vias(F, get, X, Y, act, seg)
        tol = self.params.goal_tolerance
        xy |= act & ~get(s.c_vmore) & (np.hypot(get(s.c_gx) - X, get(s.c_gy) - Y) <= tol)
        vcmd = np.zeros(F.size)
        wcmd = np.zeros(F.size)
        arrived = np.zeros(F.size, dtype=bool)
        self._turn_to_yaw(F, xy, wcmd, arrived)
        # driving along the path
        di = np.flatnonzero(~xy)
        rem = np.zeros(F.size)
        side = get(s.f_side).copy()
        if di.size:
            rem_d, vc, wc = self._drive(F, di, get, X, Y, seg, last, proj, geo, side, obst)
            if di.size == F.size:
                rem, vcmd, wcmd = rem_d, vc, wc
            else:
                rem[di] = rem_d
                vcmd[di] = vc
                wcmd[di] = wc
        # approach timer: the remaining path must shrink by APPROACH_M every window
        better = xy | (rem < get(s.f_best) - APPROACH_M)
        best = np.where(better, rem, get(s.f_best))
        btime = np.where(better, now, get(s.f_btime))
        window = APPROACH_FACTOR * self.params.stuck_time_s
        timeout = ~arrived & (now - btime >= window - 1e-9)
        stop = arrived | timeout
        any_stop = bool(stop.any())
        if any_stop:
            vcmd[stop] = 0.0
            wcmd[stop] = 0.0
        self._write_back(F, full, seg, proj, nv, xy, side, best, btime, vcmd, wcmd)
        if not any_stop:
            return _NO_ROBOTS, _NO_FLAGS
        a = np.flatnonzero(stop)
        return F[a], arrived[a]

    def _follow_compiled(self, F: np.ndarray, now: float, obst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`follow` with the per-robot arithmetic compiled (:mod:`sim.follower_kernels`);
        the lookahead heading (NumPy's ``arctan2``) and the detour search run between the two
        loops."""
        s = self.state
        p = self.params
        m = p.model
        k = F.size
        seg = np.empty(k, dtype=np.int64)
        nv = np.empty(k, dtype=np.int64)
        proj, rem, dx, dy, w = (np.empty(k) for _ in range(5))
        xy = np.empty(k, dtype=bool)
        arrived = np.empty(k, dtype=bool)
        follower_kernels.track(
            F, s.x, s.y, s.th, s.v, s.f_xy, s.f_seg, s.f_len, s.f_off, s.f_nv, s.f_vn, s.f_voff, s.f_yaw,
            s.c_ax, s.c_ay, s.c_bx, s.c_by, s.c_ex, s.c_ey, s.c_den, s.c_suf, s.c_long,
            s.c_vx, s.c_vy, s.c_vseg, s.c_vmore, s.c_gx, s.c_gy,
            s.vias, s.pts_x, s.pts_y, s.seg_len, s.suffix,
            p.goal_tolerance, p.yaw_tolerance, m.max_angular_speed, m.max_angular_accel,
            seg, nv, proj, rem, dx, dy, w, xy, arrived,
        )  # fmt: skip
        di = np.flatnonzero(~xy)
        side = s.f_side[F]
        if di.size == k:
            desired = np.arctan2(dy, dx)
            self._avoid(F, desired, rem, side, obst)
        elif di.size:
            desired = np.arctan2(dy[di], dx[di])
            sd = side[di]
            self._avoid(F[di], desired, rem[di], sd, obst)
            side[di] = sd
        else:
            desired = dx[:0]
        stop = np.empty(k, dtype=bool)
        follower_kernels.command(
            F, di, desired, s.th, seg, nv, proj, rem, w, xy, arrived, side,
            m.max_linear_speed, m.max_angular_speed, m.max_linear_accel, m.max_angular_accel,
            ROTATE_IN_PLACE_RAD, HEADING_GAIN, APPROACH_M, now, APPROACH_FACTOR * p.stuck_time_s,
            s.f_seg, s.f_nv, s.f_side, s.f_t, s.f_best, s.f_btime, s.f_xy, s.vd, s.wd, s.drives, stop,
        )  # fmt: skip
        if not stop.any():
            return _NO_ROBOTS, _NO_FLAGS
        a = np.flatnonzero(stop)
        return F[a], arrived[a]

    def _advance_segments(
        self, F: np.ndarray, get: _Gather, full: bool, X: np.ndarray, Y: np.ndarray, act: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, _Geometry]:
        """Move each active robot's segment cursor past the segments it finished (the
        projection passed the end, or within the goal tolerance of it). Returns the cursor,
        the last segment index, the projection parameter ``t`` on the current segment and its
        geometry."""
        s = self.state
        tol = self.params.goal_tolerance
        seg = get(s.f_seg).copy()
        last = get(s.f_len) - 2
        ax, ay, bx, by, ex, ey = (get(c) for c in (s.c_ax, s.c_ay, s.c_bx, s.c_by, s.c_ex, s.c_ey))
        t = np.where(get(s.c_long), ((X - ax) * ex + (Y - ay) * ey) / get(s.c_den), 1.0)
        A = np.flatnonzero(act & (seg < last) & ((t >= 1.0) | (np.hypot(bx - X, by - Y) <= tol)))
        if A.size:
            while A.size:
                seg[A] += 1
                FA = F[A]
                s.f_seg[FA] = seg[A]
                s.load_segments(FA)
                XA, YA = X[A], Y[A]
                num = (XA - s.c_ax[FA]) * s.c_ex[FA] + (YA - s.c_ay[FA]) * s.c_ey[FA]
                tA = np.where(s.c_long[FA], num / s.c_den[FA], 1.0)
                t[A] = tA
                A = A[
                    (seg[A] < last[A]) & ((tA >= 1.0) | (np.hypot(s.c_bx[FA] - XA, s.c_by[FA] - YA) <= tol))
                ]
            if not full:
                ax, ay, bx, by, ex, ey = (get(c) for c in (s.c_ax, s.c_ay, s.c_bx, s.c_by, s.c_ex, s.c_ey))
        return seg, last, t, (ax, ay, bx, by, ex, ey)

    def _pass_vias(
        self, F: np.ndarray, get: _Gather, X: np.ndarray, Y: np.ndarray, act: np.ndarray, seg: np.ndarray
    ) -> np.ndarray:
        """Count the vias each active robot passed (its cursor reached them, or it came within
        the goal tolerance); return the via cursor."""
        s = self.state
        tol = self.params.goal_tolerance
        nv = get(s.f_nv).copy()
        can = act & get(s.c_vmore)
        A = np.flatnonzero(
            can & ((seg >= get(s.c_vseg)) | (np.hypot(get(s.c_vx) - X, get(s.c_vy) - Y) <= tol))
        )
        while A.size:
            nv[A] += 1
            FA = F[A]
            s.f_nv[FA] = nv[A]
            s.load_vias(FA)
            near = np.hypot(s.c_vx[FA] - X[A], s.c_vy[FA] - Y[A]) <= tol
            A = A[s.c_vmore[FA] & ((seg[A] >= s.c_vseg[FA]) | near)]
        return nv

    def _turn_to_yaw(self, F: np.ndarray, xy: np.ndarray, wcmd: np.ndarray, arrived: np.ndarray) -> None:
        """Robots at their final position turn to the final yaw; within the yaw tolerance they
        arrived."""
        yi = np.flatnonzero(xy)
        if not yi.size:
            return
        s = self.state
        m = self.params.model
        fy = F[yi]
        err = (s.f_yaw[fy] - s.th[fy] + math.pi) % (2.0 * math.pi) - math.pi
        done = np.abs(err) <= self.params.yaw_tolerance
        arrived[yi[done]] = True
        turn = np.minimum(m.max_angular_speed, np.sqrt(2.0 * m.max_angular_accel * np.abs(err)))
        wcmd[yi] = np.where(done, 0.0, np.copysign(turn, err))

    def _drive(
        self,
        F: np.ndarray,
        di: np.ndarray,
        get: _Gather,
        X: np.ndarray,
        Y: np.ndarray,
        seg: np.ndarray,
        last: np.ndarray,
        proj: np.ndarray,
        geo: _Geometry,
        side: np.ndarray,
        obst: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(remaining path, v, w)`` of the robots ``F[di]`` driving along their path: the
        lookahead target, a detour if the way is blocked (``side`` keeps the side chosen) and
        the turn-then-drive command."""
        s = self.state
        alld = di.size == F.size

        def sub(arr: np.ndarray) -> np.ndarray:
            return arr if alld else arr[di]

        fi = F if alld else F[di]
        ax, ay, bx, by, ex, ey = geo
        tq = sub(proj)
        axd, ayd, bxd, byd = sub(ax), sub(ay), sub(bx), sub(by)
        qx = axd + tq * sub(ex)
        qy = ayd + tq * sub(ey)
        Xd, Yd = sub(X), sub(Y)
        left = np.hypot(bxd - qx, byd - qy)
        rem_d = left + sub(get(s.c_suf)) + np.hypot(qx - Xd, qy - Yd)
        tx, ty = self._lookahead(fi, sub(seg), sub(last), qx, qy, bxd, byd, left)
        desired = np.arctan2(ty - Yd, tx - Xd)
        sd = side if alld else side[di]
        self._avoid(fi, desired, rem_d, sd, obst)
        if not alld:
            side[di] = sd
        vc, wc = self._steer(desired, sub(get(s.th)), rem_d)
        return rem_d, vc, wc

    def _lookahead(
        self,
        fi: np.ndarray,
        segd: np.ndarray,
        lastd: np.ndarray,
        qx: np.ndarray,
        qy: np.ndarray,
        bxd: np.ndarray,
        byd: np.ndarray,
        left: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The lookahead point ``0.3 + 0.3 |v|`` m ahead of the projection ``(qx, qy)`` along
        the path (``(bxd, byd)`` the end of the current segment, ``left`` m away)."""
        s = self.state
        dist = 0.3 + 0.3 * np.abs(s.v[fi])
        M = np.flatnonzero((dist > left) & (segd < lastd))
        if M.size:
            PX, PY, SL = s.pts_x, s.pts_y, s.seg_len
            dM, lM, sM = dist[M], left[M], segd[M].copy()
            lastM = lastd[M]
            offM = s.f_off[fi[M]]
            qxM, qyM, bxM, byM = qx[M], qy[M], bxd[M], byd[M]
            more = np.ones(M.size, dtype=bool)
            while True:
                dM = np.where(more, dM - lM, dM)
                sM += more
                kM = offM + sM
                qxM = np.where(more, PX[kM], qxM)
                qyM = np.where(more, PY[kM], qyM)
                bxM = np.where(more, PX[kM + 1], bxM)
                byM = np.where(more, PY[kM + 1], byM)
                lM = np.where(more, SL[kM], lM)
                more = (dM > lM) & (sM < lastM)
                if not more.any():
                    break
            # copies: these may be views of the state's segment cache
            dist = dist.copy()
            left = left.copy()
            qx, qy, bxd, byd = qx.copy(), qy.copy(), bxd.copy(), byd.copy()
            dist[M], left[M], qx[M], qy[M], bxd[M], byd[M] = dM, lM, qxM, qyM, bxM, byM
        f = np.where(dist >= left, 1.0, dist / np.maximum(left, 1e-12))
        return qx + f * (bxd - qx), qy + f * (byd - qy)

    def _avoid(
        self, fi: np.ndarray, desired: np.ndarray, rem_d: np.ndarray, sd: np.ndarray, obst: np.ndarray
    ) -> None:
        """Turn ``desired`` (rad, in place) of robots ``fi`` whose way is blocked within
        :data:`AVOID_LOOKAHEAD_M` (by something not sitting on their goal) to a detour, and
        record the side chosen in ``sd`` (-1, 0, +1; 0 once the way is clear)."""
        m = self.params.model
        tol = self.params.goal_tolerance
        av = self.avoidance
        if self.compiled and av.compiled and not obst.size:
            self._avoid_compiled(fi, desired, rem_d, sd)
            return
        if self.compiled and not obst.size:
            bi = self._blocked_compiled(fi, desired, rem_d, sd)
        else:
            blk = av.corridor_free(
                fi, np.cos(desired), np.sin(desired), np.full(fi.size, AVOID_LOOKAHEAD_M), obst
            )
            blocked = (blk < AVOID_LOOKAHEAD_M) & (blk + 2.0 * m.radius + tol < rem_d)
            sd[~blocked] = 0
            bi = np.flatnonzero(blocked)
        if bi.size:
            db = desired[bi]
            sdb = sd[bi]
            k = av.detour(fi[bi], db, sdb, obst)
            anyok = k >= 0
            chosen = OFFSETS[k]
            desired[bi] = np.where(anyok, db + chosen, db)
            sd[bi] = np.where(anyok, np.where(chosen > 0, 1, -1), sdb)

    def _grown_scratch(self) -> np.ndarray:
        """The compiled passes' scratch rows (three float rows and ``_rows``), grown to the
        fleet's capacity when robots were added."""
        s = self.state
        if self._scratch.shape[1] < s.n:
            self._scratch = np.zeros((3, s.capacity))
            self._rows = np.zeros(s.capacity, dtype=np.int64)
        return self._scratch

    def _avoid_compiled(self, fi: np.ndarray, desired: np.ndarray, rem_d: np.ndarray, sd: np.ndarray) -> None:
        """:meth:`_avoid` without dynamic obstacles as one compiled call
        (:func:`sim.detour_kernels.avoid`: the corridor test of :meth:`_blocked_compiled`, the
        detour search of ``Avoidance.detour`` and the turn to the detour)."""
        s = self.state
        av = self.avoidance
        hx, hy, best = self._grown_scratch()
        contact, lat = av.contact, av.lat
        pairs = av.pairs
        reach = math.hypot(AVOID_LOOKAHEAD_M + contact, lat)
        pi, pj = pairs.index_pairs(reach)
        # index_pairs() gives every pair once the reach passes the pair radius
        way_reach2 = reach * reach if reach < pairs.radius else math.inf
        d_reach = math.hypot(AVOID_CLEAR_M + contact, lat)
        a_all, dx_all, dy_all, d2_all = pairs.candidates(d_reach)
        loc = av.scratch_rows()
        fp = av.footprints
        g = fp.grid
        detour_kernels.avoid(
            fi, desired, rem_d, sd, s.n, pi, pj, pairs.x0, pairs.y0, way_reach2, AVOID_LOOKAHEAD_M,
            2.0 * self.params.model.radius, self.params.goal_tolerance, hx, hy, best, self._rows,
            a_all, dx_all, dy_all, d2_all, d_reach * d_reach, loc, OFFSETS, COS_OFFSETS, SIN_OFFSETS, OFFSET_BITS,
            FIRST_FREE, contact, lat, AVOID_CLEAR_M, g.origin_x, g.origin_y, g.resolution, g.width, g.height,
            fp.cells, fp.clear_cells(), fp.samples, s.x, s.y,
        )  # fmt: skip

    def _blocked_compiled(
        self, fi: np.ndarray, desired: np.ndarray, rem_d: np.ndarray, sd: np.ndarray
    ) -> np.ndarray:
        """The corridor test of :meth:`_avoid` as one compiled pass
        (:func:`sim.follower_kernels.way_blocked`, no dynamic obstacles): the blocked rows of
        ``fi``; ``sd`` is 0 for the others."""
        s = self.state
        av = self.avoidance
        hx, hy, best = self._grown_scratch()
        contact, lat = av.contact, av.lat
        reach = math.hypot(AVOID_LOOKAHEAD_M + contact, lat)
        pairs = av.pairs
        pi, pj = pairs.index_pairs(reach)
        # index_pairs() gives every pair once the reach passes the pair radius
        reach2 = reach * reach if reach < pairs.radius else math.inf
        margin = 2.0 * self.params.model.radius
        k = follower_kernels.way_blocked(
            fi, desired, rem_d, sd, s.n, pi, pj, pairs.x0, pairs.y0, reach2, contact, lat,
            AVOID_LOOKAHEAD_M, margin, self.params.goal_tolerance, hx, hy, best, self._rows,
        )  # fmt: skip
        return self._rows[:k].copy()

    def _steer(self, desired: np.ndarray, th: np.ndarray, rem_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Turn-then-drive: rotate in place above :data:`ROTATE_IN_PLACE_RAD` of heading error,
        else drive, slower with the error and to stop at the end of the path."""
        m = self.params.model
        err = (desired - th + math.pi) % (2.0 * math.pi) - math.pi
        aerr = np.abs(err)
        rot = aerr > ROTATE_IN_PLACE_RAD
        turn = np.minimum(m.max_angular_speed, np.sqrt(2.0 * m.max_angular_accel * aerr))
        vdrive = m.max_linear_speed * (1.0 - 0.6 * aerr / ROTATE_IN_PLACE_RAD)
        vdrive = np.minimum(vdrive, np.sqrt(2.0 * m.max_linear_accel * 0.8 * rem_d))
        wdrive = np.clip(HEADING_GAIN * err, -m.max_angular_speed, m.max_angular_speed)
        vc = np.where(rot, 0.0, vdrive)
        wc = np.where(rot, np.copysign(turn, err), wdrive)
        return vc, wc

    def _write_back(
        self,
        F: np.ndarray,
        full: bool,
        seg: np.ndarray,
        proj: np.ndarray,
        nv: np.ndarray,
        xy: np.ndarray,
        side: np.ndarray,
        best: np.ndarray,
        btime: np.ndarray,
        vcmd: np.ndarray,
        wcmd: np.ndarray,
    ) -> None:
        """Store the cursors, flags, approach timer and commands of robots ``F``."""
        s = self.state
        if full:
            n = s.n
            s.f_seg[:n] = seg
            s.f_t[:n] = proj
            s.f_nv[:n] = nv
            s.f_xy[:n] = xy
            s.f_side[:n] = side
            s.f_best[:n] = best
            s.f_btime[:n] = btime
            s.vd[:n] = vcmd
            s.wd[:n] = wcmd
            np.not_equal(vcmd, 0.0, out=s.drives[:n])
        else:
            s.f_seg[F] = seg
            s.f_t[F] = proj
            s.f_nv[F] = nv
            s.f_xy[F] = xy
            s.f_side[F] = side
            s.f_best[F] = best
            s.f_btime[F] = btime
            s.vd[F] = vcmd
            s.wd[F] = wcmd
            s.drives[F] = vcmd != 0.0
