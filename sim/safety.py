"""Safety: what keeps the simulated robots from driving into things, and what counts contacts.

* :meth:`Safety.reactive_stop` is the collision monitor: a moving robot looks along the
  corridor of its width in its direction of travel and limits its speed so it can stop
  :data:`STOP_GAP_M` before the first robot or dynamic obstacle in it.
* :meth:`Safety.move` integrates the commanded motion at the mid-step heading and refuses a
  move that would put the footprint on a static obstacle or off the map, or into a dynamic
  obstacle (sliding along it when one axis of the move is free).
* :meth:`Safety.free_distance` answers the behaviors' "collision ahead" question (BackUp,
  DriveOnHeading) for one robot.
* :class:`Contacts` counts robot-robot contacts (center distance < 2 radius): a pair that
  starts touching is one collision event.

Units m, rad, s; frame ``map``. Robots see each other where they were at the start of the step
(the neighbor pairs of :class:`sim.spatial.NeighborPairs`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fleet.robots import SimParams
from sim import kernels, motion_kernels
from sim.avoidance import Avoidance, corridor_gaps
from sim.footprint import FootprintGrid
from sim.history import EVENTS_KEPT, trim_oldest
from sim.planner import GridPlanner
from sim.spatial import NeighborPairs
from sim.state import FleetState

#: The reactive layer stops a robot this far (m) from the robot or obstacle ahead.
STOP_GAP_M = 0.1


class Safety:
    """The reactive stop, the refusal of motion into obstacles and the free distance ahead,
    over ``state`` (see the module docstring)."""

    def __init__(
        self,
        state: FleetState,
        params: SimParams,
        avoidance: Avoidance,
        footprints: FootprintGrid,
        planner: GridPlanner,
    ) -> None:
        self.state = state
        self.params = params
        self.avoidance = avoidance
        self.footprints = footprints
        self.planner = planner

    def reactive_stop(self, v: np.ndarray, dt: float, obst: np.ndarray) -> None:
        """Limit the commanded speeds ``v`` (m/s, one per robot, in place) so each robot can
        stop :data:`STOP_GAP_M` before whatever is ahead in its direction of travel."""
        m = self.params.model
        mv = np.flatnonzero(v != 0.0)
        if not mv.size:
            return
        vm = v[mv]
        direction = np.where(vm > 0, 1.0, -1.0)
        look = vm * vm / (2.0 * m.max_linear_accel) + STOP_GAP_M + np.abs(vm) * dt + 0.05
        thm = self.state.th[: v.size][mv]
        hx = np.cos(thm) * direction
        hy = np.sin(thm) * direction
        free = self.avoidance.corridor_free(mv, hx, hy, look, obst)
        lim = free < look
        if lim.any():
            room = np.maximum(free - STOP_GAP_M, 0.0)
            vmax = np.minimum(np.sqrt(2.0 * m.max_linear_accel * room), room / dt)
            cut = lim & (np.abs(vm) > vmax)
            v[mv[cut]] = direction[cut] * vmax[cut]

    def limit_stop_move(
        self, vd: np.ndarray, wd: np.ndarray, dt: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The acceleration and speed limits, :meth:`reactive_stop` and :meth:`move` of every
        robot in two compiled loops (:mod:`sim.motion_kernels`), for a step without dynamic
        obstacles. Returns ``(w, ds, dtheta, moved)``: the limited turn rates and what
        :meth:`move` returns."""
        s = self.state
        m = self.params.model
        n = vd.size
        v, w, hx, hy, look, ds, dth = (np.empty(n) for _ in range(7))
        longest = motion_kernels.limit_and_look(
            vd, wd, s.v[:n], s.w[:n], s.stalled[:n], s.halt[:n], s.battery[:n], s.th[:n], dt,
            m.max_linear_accel, m.max_angular_accel, m.max_linear_speed, m.max_angular_speed, STOP_GAP_M,
            v, w, hx, hy, look,
        )  # fmt: skip
        free = look.copy()
        if longest > 0.0:
            self.avoidance.corridor_min_all(hx, hy, look, longest, free)
        moved = np.empty(n, dtype=bool)
        fp = self.footprints
        g = fp.grid
        motion_kernels.stop_and_move(
            v, w, free, look, s.x[:n], s.y[:n], s.th[:n], s.v[:n], s.w[:n], s.dist[:n], dt,
            m.max_linear_accel, STOP_GAP_M, g.origin_x, g.origin_y, g.resolution, g.width, g.height,
            fp.cells, ds, dth, moved,
        )  # fmt: skip
        return w, ds, dth, moved

    def move(
        self, v: np.ndarray, w: np.ndarray, dt: float, obst: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Move every robot by ``v``, ``w`` (m/s, rad/s) for ``dt`` s, refusing moves into
        obstacles; store pose, velocities and odometer. Returns ``(ds, dtheta, moved)``: the
        signed distance each robot moved along its heading (m), its rotation (rad) and
        whether it translated."""
        s = self.state
        n = v.size
        x = s.x[:n]
        y = s.y[:n]
        th = s.th[:n]
        ds = v * dt
        dth = w * dt
        moved = np.zeros(n, dtype=bool)
        mv = np.flatnonzero(ds != 0.0)
        if mv.size:
            mid = th[mv] + 0.5 * dth[mv]
            ox, oy = x[mv], y[mv]
            dsm = ds[mv]
            nx = ox + dsm * np.cos(mid)
            ny = oy + dsm * np.sin(mid)
            ok = self.footprints.free(nx, ny)
            if obst.size:
                ok &= ~self.enters(ox, oy, nx, ny, obst)
            bad = np.flatnonzero(~ok)
            if bad.size:
                self._slide(bad, ox, oy, nx, ny, ok, obst)
                okm = mv[ok]
                nx, ny, ox, oy = nx[ok], ny[ok], ox[ok], oy[ok]
                nok = mv[~ok]
                ds[nok] = 0.0
                v[nok] = 0.0
            else:
                okm = mv
            step_len = np.hypot(nx - ox, ny - oy)
            dsk = np.copysign(step_len, ds[okm])
            ds[okm] = dsk
            v[okm] = dsk / dt
            x[okm] = nx
            y[okm] = ny
            moved[okm] = True
        s.th[:n] = (th + dth + math.pi) % (2.0 * math.pi) - math.pi
        s.v[:n] = v
        s.w[:n] = w
        s.dist[:n] += np.abs(ds)
        return ds, dth, moved

    def _slide(
        self,
        bad: np.ndarray,
        ox: np.ndarray,
        oy: np.ndarray,
        nx: np.ndarray,
        ny: np.ndarray,
        ok: np.ndarray,
        obst: np.ndarray,
    ) -> None:
        """For the refused moves ``bad`` (from ``(ox, oy)`` to ``(nx, ny)``), try the move along
        its larger axis alone, then along the other; store the first allowed one in ``nx``,
        ``ny`` and mark it in ``ok`` (in place)."""
        ex, ey = nx[bad] - ox[bad], ny[bad] - oy[bad]
        xfirst = np.abs(ex) >= np.abs(ey)
        bx, by = ox[bad], oy[bad]
        found = np.zeros(bad.size, dtype=bool)
        rx, ry = bx.copy(), by.copy()
        for first in (True, False):
            use_x = xfirst if first else ~xfirst
            cx = np.where(use_x, bx + ex, bx)
            cy = np.where(use_x, by, by + ey)
            good = ~found & ((cx != bx) | (cy != by)) & self.footprints.free(cx, cy)
            if obst.size:
                good &= ~self.enters(bx, by, cx, cy, obst)
            rx = np.where(good, cx, rx)
            ry = np.where(good, cy, ry)
            found |= good
        nx[bad] = rx
        ny[bad] = ry
        ok[bad] = found

    def enters(
        self, ox: np.ndarray, oy: np.ndarray, nx: np.ndarray, ny: np.ndarray, obst: np.ndarray
    ) -> np.ndarray:
        """True where the move from ``(ox, oy)`` to ``(nx, ny)`` ends inside a dynamic
        obstacle (within radius + obstacle radius) and closer to it than before."""
        out = np.zeros(ox.shape, dtype=bool)
        r = self.params.model.radius
        for qx, qy, qr in obst.tolist():
            d_new = np.hypot(nx - qx, ny - qy)
            out |= (d_new < r + qr) & (d_new < np.hypot(ox - qx, oy - qy))
        return out

    def free_distance(
        self,
        i: int,
        direction: float,
        lookahead: float,
        static: bool,
        heading: float | None,
        obst: np.ndarray,
    ) -> float:
        """Distance (m) the center of robot ``i`` can travel straight along ``heading`` (default:
        its current yaw; ``direction`` +1 forward, -1 backward) before its footprint touches
        another robot or a dynamic obstacle of ``obst`` (and, if ``static``, a static obstacle
        or the map edge), capped at ``lookahead``. Only things in the corridor of the robot's
        width ahead count."""
        r = self.params.model.radius
        s = self.state
        n = s.n
        yaw = float(s.th[i]) if heading is None else heading
        hx = math.cos(yaw) * direction
        hy = math.sin(yaw) * direction
        x, y = float(s.x[i]), float(s.y[i])
        others = np.ones(n, dtype=bool)
        others[i] = False
        dx = s.x[:n][others] - x
        dy = s.y[:n][others] - y
        best = lookahead
        if dx.size:
            gaps = corridor_gaps(dx, dy, hx, hy, 2.0 * r, np.full(dx.size, lookahead))
            best = min(best, float(gaps.min()))
        for ox, oy, orad in obst.tolist():
            g = corridor_gaps(np.array([ox - x]), np.array([oy - y]), hx, hy, r + orad, np.array([best]))
            best = min(best, float(g[0]))
        if static and best > 0.0:
            stepd = 0.5 * self.footprints.grid.resolution
            sd = stepd
            while sd <= best:
                if not self.planner.footprint_free(x + hx * sd, y + hy * sd):
                    best = max(0.0, sd - stepd)
                    break
                sd += stepd
        return best


class Contacts:
    """Robot-robot contacts: ``total`` collision events and ``events`` ``(t, ns_a, ns_b, x,
    y)`` (namespaces in order, midpoint in the ``map`` frame; the last :data:`sim.history.EVENTS_KEPT` at
    least), and each robot's count in the state's ``collisions``."""

    def __init__(
        self, state: FleetState, params: SimParams, pairs: NeighborPairs, compiled: bool = False
    ) -> None:
        self.state = state
        self.params = params
        self.pairs = pairs
        #: find the touching pairs in one compiled pass (:func:`sim.kernels.touching_pairs`)
        self.compiled = compiled
        self._found = np.empty((2, 0), dtype=np.int64)
        self.total = 0
        self.events: list[tuple[float, str, str, float, float]] = []
        self._touching: set[tuple[int, int]] = set()

    def count(self, now: float, name: Callable[[int], str]) -> None:
        """Count the pairs that started touching at time ``now`` (s); ``name(i)`` is robot
        ``i``'s namespace."""
        s = self.state
        m = self.params.model
        d2 = 2.0 * m.radius
        # a pair touching now was closer than 2 * radius + both robots' longest step before it
        before = d2 + 2.0 * m.max_linear_speed * self.params.step_s + 1e-6
        p = self.pairs
        if before <= p.short:
            pa, pb, pd2 = p.si, p.sj, p.sd2
        else:
            pa, pb, pd2 = p.i, p.j, p.d2
        if self.compiled:
            if self._found.shape[1] < pa.size:
                self._found = np.empty((2, max(pa.size, 2 * self._found.shape[1])), dtype=np.int64)
            ta, tb = self._found
            k = kernels.touching_pairs(pa, pb, pd2, before * before, s.x, s.y, d2, ta, tb)
            touching = set(zip(ta[:k].tolist(), tb[:k].tolist(), strict=True)) if k else set()
        else:
            half = np.flatnonzero((pa < pb) & (pd2 < before * before))
            a, b = pa[half], pb[half]
            close = np.hypot(s.x[b] - s.x[a], s.y[b] - s.y[a]) < d2
            touching = set(zip(a[close].tolist(), b[close].tolist(), strict=True)) if close.any() else set()
        new = touching - self._touching
        if new:
            named = []
            for i, j in new:
                na, nb = name(i), name(j)
                named.append((na, nb, i, j) if na < nb else (nb, na, j, i))
            for na, nb, i, j in sorted(named):
                s.collisions[i] += 1
                s.collisions[j] += 1
                self.total += 1
                self.events.append((now, na, nb, 0.5 * float(s.x[i] + s.x[j]), 0.5 * float(s.y[i] + s.y[j])))
            trim_oldest(self.events, EVENTS_KEPT)
        self._touching = touching
