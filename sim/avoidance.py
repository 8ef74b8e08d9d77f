"""Local avoidance: corridor checks and detour headings around robots and dynamic obstacles.

A robot heading along a unit vector sweeps a *corridor* as wide as two robot radii plus
:data:`CORRIDOR_MARGIN_M`; :meth:`Avoidance.corridor_free` gives, for many robots at once, how
far each can go before its footprint touches another robot or a dynamic obstacle in that
corridor (the safety stop and the path follower's "is the way blocked" test both use it). A
path-following robot whose way is blocked within :data:`AVOID_LOOKAHEAD_M` steers to the first
of the :data:`AVOID_OFFSETS` (tried in an order that keeps the side it already chose) whose
heading is free for :data:`AVOID_CLEAR_M`, static map included (:meth:`Avoidance.detour`).

The loops over neighbor pairs (the corridor test of every pair, and of every pair and detour
heading) run compiled (:mod:`sim.kernels`) where numba is installed, else as the NumPy
expressions :func:`corridor_min_numpy` and :func:`pair_blocks_numpy`, which compute the same
floats. Units m, rad; frame ``map``.
"""

from __future__ import annotations

import math

import numpy as np

from sim import detour_kernels, kernels
from sim.footprint import FootprintGrid
from sim.spatial import NeighborPairs
from sim.state import FleetState

#: Extra half-width (m) of the corridor ahead that the corridor checks watch.
CORRIDOR_MARGIN_M = 0.05
#: A path follower tries to steer around a robot or dynamic obstacle closer than this (m)
#: in the direction it wants to drive.
AVOID_LOOKAHEAD_M = 1.5
#: A detour heading must be free (static map included) for this far (m).
AVOID_CLEAR_M = 0.8
#: Detour heading offsets (rad) tried in order: smallest first, the right-hand side first, so
#: two robots meeting head-on both keep right and pass each other.
AVOID_OFFSETS = (-0.35, 0.35, -0.7, 0.7, -1.05, 1.05, -1.4, 1.4, -1.75, 1.75, -2.1, 2.1)

#: Detour offsets and the order they are tried in, by the side already chosen (-1, 0, +1).
OFFSETS = np.array(AVOID_OFFSETS)
_ORDERS = np.array(
    [
        [k for k, o in enumerate(AVOID_OFFSETS) if o < 0] + [k for k, o in enumerate(AVOID_OFFSETS) if o > 0],
        list(range(len(AVOID_OFFSETS))),
        [k for k, o in enumerate(AVOID_OFFSETS) if o > 0] + [k for k, o in enumerate(AVOID_OFFSETS) if o < 0],
    ],
    dtype=np.int64,
)
#: The detour offsets sorted (``_SORTED_K``: the index in ``OFFSETS`` of each; ``_SORTED_POS``
#: the inverse): bit ``j`` of a robot's blocked mask is the ``j``-th smallest offset.
_SORTED_K = np.argsort(OFFSETS, kind="stable")
_SORTED_POS = np.argsort(_SORTED_K, kind="stable")
#: ``_BIT[j] = 1 << j``; ``_FIRST_FREE[side + 1, mask]``: the index in ``OFFSETS`` of the first
#: offset in the order ``_ORDERS[side + 1]`` whose sorted position is not set in ``mask``, -1
#: if every one is.
_BIT = np.left_shift(1, np.arange(OFFSETS.size, dtype=np.int64))
_FIRST_FREE = np.full((3, 1 << OFFSETS.size), -1, dtype=np.int64)
for _i, _order in enumerate(_ORDERS):
    _free = ((np.arange(1 << OFFSETS.size)[:, None] >> _SORTED_POS[_order][None, :]) & 1) == 0
    _FIRST_FREE[_i] = np.where(_free.any(axis=1), _order[_free.argmax(axis=1)], -1)
#: What the compiled detour search (:mod:`sim.detour_kernels`) reads: the offsets' cosines
#: and sines (it turns a neighbor's offset by them), each offset's bit in a blocked mask, and
#: the first free offset by side and mask (``_FIRST_FREE``).
COS_OFFSETS = np.cos(OFFSETS)
SIN_OFFSETS = np.sin(OFFSETS)
OFFSET_BITS = _BIT[_SORTED_POS]
FIRST_FREE = _FIRST_FREE


def corridor_gaps(
    dx: np.ndarray,
    dy: np.ndarray,
    hx: np.ndarray | float,
    hy: np.ndarray | float,
    contact: float,
    cap: np.ndarray,
) -> np.ndarray:
    """How far along unit heading ``(hx, hy)`` a disc can move before its center comes within
    ``contact`` of a point at offset ``(dx, dy)``; ``cap`` where the point is not ahead in the
    corridor; 0 if already in contact and the point is ahead. Element-wise."""
    along = dx * hx + dy * hy
    lateral = np.abs(dx * hy - dy * hx)
    inner = along - np.sqrt(np.maximum(contact * contact - lateral * lateral, 0.0))
    gap = np.maximum(0.0, np.where(lateral >= contact, along - contact, inner))
    return np.where((along <= 0.0) | (lateral >= contact + CORRIDOR_MARGIN_M), cap, gap)


def corridor_min_numpy(
    a: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    hx: np.ndarray,
    hy: np.ndarray,
    cap: np.ndarray,
    contact: float,
    lat: float,
    best: np.ndarray,
) -> None:
    """:func:`sim.kernels.corridor_min` as whole-array NumPy (the same floats): lower
    ``best[i]`` to the corridor gap of every pair ``(i = a[p], offset dx[p], dy[p])`` whose
    neighbor is ahead along ``(hx[i], hy[i])``, inside the corridor and closer than ``cap[i] +
    contact``."""
    along = dx * hx[a] + dy * hy[a]
    lateral = np.abs(dx * hy[a] - dy * hx[a])
    hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < cap[a] + contact))
    if hit.size:
        al, la = along[hit], lateral[hit]
        inner = al - np.sqrt(np.maximum(contact * contact - la * la, 0.0))
        gap = np.maximum(np.where(la >= contact, al - contact, inner), 0.0)
        np.minimum.at(best, a[hit], gap)


def pair_blocks_numpy(
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    db: np.ndarray,
    offsets: np.ndarray,
    bits: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    blocked: np.ndarray,
) -> None:
    """:func:`sim.kernels.pair_blocks` as whole-array NumPy (the same floats and bits): every
    (pair, offset) of the blocked robots' pairs closer than ``sqrt(reach2)``."""
    sel = np.flatnonzero((d2_all < reach2) & (loc[a_all] >= 0))
    if not sel.size:
        return
    r, dx, dy = loc[a_all[sel]], dx_all[sel], dy_all[sel]
    kk = offsets.size
    p = np.repeat(np.arange(r.size), kk)
    k = np.tile(np.arange(kk), r.size)
    h = db[r[p]] + offsets[k]
    hx, hy = np.cos(h), np.sin(h)
    along = dx[p] * hx + dy[p] * hy
    lateral = np.abs(dx[p] * hy - dy[p] * hx)
    hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < cap + contact))
    al, la = along[hit], lateral[hit]
    inner = al - np.sqrt(np.maximum(contact * contact - la * la, 0.0))
    gap = np.maximum(np.where(la >= contact, al - contact, inner), 0.0)
    bad = hit[gap < cap]
    np.bitwise_or.at(blocked, r[p[bad]], bits[k[bad]])


class Avoidance:
    """Corridor checks and detour search over the fleet's :class:`~sim.state.FleetState`,
    its neighbor pairs and the static footprint grid, for robots of ``radius`` m.
    ``compiled`` (default :func:`sim.kernels.enabled`): the pair loops compiled, else NumPy."""

    def __init__(
        self,
        state: FleetState,
        pairs: NeighborPairs,
        footprints: FootprintGrid,
        radius: float,
        compiled: bool | None = None,
    ) -> None:
        self.state = state
        self.pairs = pairs
        self.footprints = footprints
        self.radius = radius
        self.contact = contact = 2.0 * radius
        self.lat = contact + CORRIDOR_MARGIN_M
        self.compiled = kernels.enabled() if compiled is None else compiled and kernels.ready()
        self._pair_blocks_fn = kernels.pair_blocks if self.compiled else pair_blocks_numpy
        #: each robot's row among the blocked robots of a detour search (-1: not blocked)
        self._loc = np.zeros(0, dtype=np.int64)

    def corridor_free(
        self, idx: np.ndarray, hx: np.ndarray, hy: np.ndarray, cap: np.ndarray, obst: np.ndarray
    ) -> np.ndarray:
        """For robots ``idx`` (increasing indices) heading along unit ``(hx, hy)`` (arrays over
        ``idx``): distance (m) to the first robot or dynamic obstacle (rows ``(x, y, radius)``
        of ``obst``) in the corridor ahead, capped at ``cap`` (an array over ``idx``).

        Works on every neighbor pair at once: a robot outside ``idx`` gets the heading
        ``(0, 0)``, so nothing is ahead of it and its pairs find nothing."""
        if not idx.size:
            return np.zeros(0)
        s = self.state
        n = s.n
        contact, lat = self.contact, self.lat
        reach = math.hypot(float(cap.max()) + contact, lat)
        if idx.size == n:
            hxf, hyf, capf = hx, hy, cap
        else:
            hxf = np.zeros(n)
            hyf = np.zeros(n)
            capf = np.zeros(n)
            hxf[idx] = hx
            hyf[idx] = hy
            capf[idx] = cap
        best = capf.copy()
        # only what is ahead, in the corridor and closer than the cap can limit
        if self.compiled:
            a, dx, dy, d2 = self.pairs.candidates(reach)
            # within() keeps every pair once the reach passes the pair radius
            reach2 = reach * reach if reach < self.pairs.radius else math.inf
            kernels.corridor_min(a, dx, dy, d2, reach2, hxf, hyf, capf, contact, lat, best)
        else:
            a, dx, dy, _ = self.pairs.within(reach)
            if a.size:
                corridor_min_numpy(a, dx, dy, hxf, hyf, capf, contact, lat, best)
        if idx.size != n:
            best = best[idx]
        if obst.size:
            sx = s.x[idx]
            sy = s.y[idx]
            for qx, qy, qr in obst.tolist():
                best = np.minimum(best, corridor_gaps(qx - sx, qy - sy, hx, hy, self.radius + qr, best))
        return best

    def corridor_min_all(
        self, hx: np.ndarray, hy: np.ndarray, cap: np.ndarray, longest: float, best: np.ndarray
    ) -> None:
        """:meth:`corridor_free` of every robot, compiled, without dynamic obstacles: lower
        ``best`` (one entry per robot, in place) to the distance to the first robot in the
        corridor along ``(hx, hy)`` (``(0, 0)``: none), capped at ``cap``; ``longest`` is
        ``cap.max()`` of the robots with a heading."""
        contact, lat = self.contact, self.lat
        reach = math.hypot(longest + contact, lat)
        a, dx, dy, d2 = self.pairs.candidates(reach)
        reach2 = reach * reach if reach < self.pairs.radius else math.inf
        kernels.corridor_min(a, dx, dy, d2, reach2, hx, hy, cap, contact, lat, best)

    def detour(self, fb: np.ndarray, db: np.ndarray, side: np.ndarray, obst: np.ndarray) -> np.ndarray:
        """The detour of each blocked robot ``fb[r]`` that wants to go along ``db[r]`` (rad):
        the index in ``OFFSETS`` of the first offset, in the order ``_ORDERS[side[r] + 1]``,
        whose heading ``db[r] + offset`` is free of robots and dynamic obstacles for
        :data:`AVOID_CLEAR_M` and keeps the footprint off static obstacles along the way
        (footprint samples every half cell); -1 if there is none. "Free" is exactly what the
        corridor test of :meth:`corridor_free` capped at ``AVOID_CLEAR_M`` decides.

        The blocked headings of each robot are a bit mask over the sorted offsets, set by its
        neighbors (:meth:`_pair_blocks`), the dynamic obstacles (:meth:`_obstacle_blocks`)
        and the static map (:meth:`_static_blocks`); the first free offset in order comes
        from a table over (side, mask)."""
        blocked = np.zeros(fb.size, dtype=np.int64)  # bit j: the j-th smallest offset is blocked
        if self.compiled:
            # neighbors and the static map in one pass; a bit set twice is set once, so the
            # dynamic obstacles' bits may come after
            self._compiled_blocks(fb, db, blocked)
            if obst.size:
                blocked |= self._obstacle_blocks(fb, db, obst)
        else:
            self._pair_blocks(fb, db, blocked)
            if obst.size:
                blocked |= self._obstacle_blocks(fb, db, obst)
            self._static_blocks(fb, db, blocked)
        out: np.ndarray = _FIRST_FREE[side + 1, blocked]
        return out

    def scratch_rows(self) -> np.ndarray:
        """Each robot's row among the blocked robots of a compiled detour search: -1 for every
        robot, as the search leaves it (sized for the fleet's capacity)."""
        if self._loc.size < self.state.n:
            self._loc = np.full(self.state.capacity, -1, dtype=np.int64)
        return self._loc

    def _compiled_blocks(self, fb: np.ndarray, db: np.ndarray, blocked: np.ndarray) -> None:
        """:meth:`_pair_blocks` and :meth:`_static_blocks` as one compiled pass
        (:func:`sim.detour_kernels.detour_blocks`)."""
        s = self.state
        contact, lat, cap = self.contact, self.lat, AVOID_CLEAR_M
        reach = math.hypot(cap + contact, lat)
        a_all, dx_all, dy_all, d2_all = self.pairs.candidates(reach)
        loc = self.scratch_rows()
        loc[fb] = np.arange(fb.size)
        fp = self.footprints
        g = fp.grid
        detour_kernels.detour_blocks(
            fb, a_all, dx_all, dy_all, d2_all, reach * reach, loc, db, s.x[fb], s.y[fb], np.cos(db), np.sin(db),
            OFFSETS, COS_OFFSETS,
            SIN_OFFSETS, OFFSET_BITS, contact, lat, cap, g.origin_x, g.origin_y, g.resolution, g.width,
            g.height, fp.cells, fp.clear_cells(), fp.samples, blocked,
        )  # fmt: skip
        loc[fb] = -1

    def _pair_blocks(self, fb: np.ndarray, db: np.ndarray, blocked: np.ndarray) -> None:
        """Set the bits of the offsets that neighbors block: the exact corridor test of every
        (pair, offset) (:func:`sim.kernels.pair_blocks` or :func:`pair_blocks_numpy`)."""
        n = self.state.n
        contact, lat, cap = self.contact, self.lat, AVOID_CLEAR_M
        reach = math.hypot(cap + contact, lat)
        # the compiled loop tests d2 itself
        pick = self.pairs.candidates if self.compiled else self.pairs.within
        a_all, dx_all, dy_all, d2_all = pick(reach)
        if not a_all.size:
            return
        loc = np.full(n, -1, dtype=np.int64)
        loc[fb] = np.arange(fb.size)
        self._pair_blocks_fn(
            a_all,
            dx_all,
            dy_all,
            d2_all,
            reach * reach,
            loc,
            db,
            OFFSETS,
            _BIT[_SORTED_POS],
            contact,
            lat,
            cap,
            blocked,
        )

    def _obstacle_blocks(self, fb: np.ndarray, db: np.ndarray, obst: np.ndarray) -> np.ndarray:
        """Bit masks of the offsets whose heading meets a dynamic obstacle within the clearance."""
        s = self.state
        nb = fb.size
        kk = OFFSETS.size
        cap = AVOID_CLEAR_M
        flat = np.arange(nb * kk)
        h = db[flat // kk] + OFFSETS[flat % kk]
        hx2 = np.cos(h).reshape(nb, kk)
        hy2 = np.sin(h).reshape(nb, kk)
        best = np.full((nb, kk), cap)
        sx = s.x[fb][:, None]
        sy = s.y[fb][:, None]
        for qx, qy, qr in obst.tolist():
            best = np.minimum(best, corridor_gaps(qx - sx, qy - sy, hx2, hy2, self.radius + qr, best))
        masks: np.ndarray = ((best < cap)[:, _SORTED_K] * _BIT[None, :]).sum(axis=1)
        return masks

    def _static_blocks(self, fb: np.ndarray, db: np.ndarray, blocked: np.ndarray) -> None:
        """Set the bits of the free offsets whose straight move of ``AVOID_CLEAR_M`` puts the
        footprint on a static obstacle. A robot whose cell is in the clear (no blocked footprint
        cell within the clearance + a cell diagonal) cannot meet one; only the others sample
        their free headings on the footprint grid."""
        s = self.state
        kk = OFFSETS.size
        fp = self.footprints
        xb = s.x[fb]
        yb = s.y[fb]
        nc = np.flatnonzero(~fp.clear(xb, yb))
        if not nc.size:
            return
        free = ((blocked[nc, None] >> _SORTED_POS[None, :]) & 1) == 0
        rb, ro = np.nonzero(free)
        if not rb.size:
            return
        rb = nc[rb]
        flat = rb * kk + ro
        h = db[flat // kk] + OFFSETS[flat % kk]
        hx, hy = np.cos(h), np.sin(h)
        smp = fp.samples
        cx = xb[rb][:, None] + hx[:, None] * smp[None, :]
        cy = yb[rb][:, None] + hy[:, None] * smp[None, :]
        off = np.flatnonzero(~fp.free(cx, cy).all(axis=1))
        if off.size:
            np.bitwise_or.at(blocked, rb[off], _BIT[_SORTED_POS[ro[off]]])
