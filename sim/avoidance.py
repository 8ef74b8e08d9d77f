"""Local avoidance: corridor checks and detour headings around robots and dynamic obstacles.

A robot heading along a unit vector sweeps a *corridor* as wide as two robot radii plus
:data:`CORRIDOR_MARGIN_M`; :meth:`Avoidance.corridor_free` gives, for many robots at once, how
far each can go before its footprint touches another robot or a dynamic obstacle in that
corridor (the safety stop and the path follower's "is the way blocked" test both use it). A
path-following robot whose way is blocked within :data:`AVOID_LOOKAHEAD_M` steers to the first
of the :data:`AVOID_OFFSETS` (tried in an order that keeps the side it already chose) whose
heading is free for :data:`AVOID_CLEAR_M`, static map included (:meth:`Avoidance.detour`).

The detour search is the step's most expensive part, so it avoids per-heading arithmetic
where it can without changing its answer: for a neighbor at distance ``d`` the blocked
headings form at most three angle intervals with closed-form ends
(:meth:`Avoidance._blocks`), judged with lookup tables over angles and distances; only
(pair, heading) combinations near an interval end get the exact corridor test. Units m, rad;
frame ``map``.
"""

from __future__ import annotations

import math

import numpy as np

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
#: the inverse) and all their copies 2 pi below and above: ``_EXT``, sorted, is the three
#: sorted copies one after the other, so slot ``s`` is sorted offset ``s % K``.
_SORTED_K = np.argsort(OFFSETS, kind="stable")
_SORTED_POS = np.argsort(_SORTED_K, kind="stable")
_EXT = np.concatenate(
    (OFFSETS[_SORTED_K] - 2.0 * math.pi, OFFSETS[_SORTED_K], OFFSETS[_SORTED_K] + 2.0 * math.pi)
)
_EXT_K = np.tile(_SORTED_K, 3)
assert bool(np.all(np.diff(_EXT) > 0.0)), "the detour offsets must span less than 2 pi"
#: Angular margin (rad) far above the rounding of the angles involved (below 1e-14 rad): an
#: offset this far inside or outside an interval of blocked headings is judged without the
#: exact test; the window of a neighbor is widened by it.
_ANGLE_MARGIN = 1e-5
#: Distance margin (m) around the distances where the blocked intervals change shape, and the
#: bin of the table that finds the distances outside it.
_DIST_MARGIN = 1e-3
_JUDGED_BIN = 1e-4
#: Lookup tables over angles in [-4 pi, 4 pi], in bins of ``_EXT_BIN`` rad from ``_EXT_LO``:
#: ``_EXT_BELOW[b]`` / ``_EXT_UPTO[b]`` count the slots below the start / end of bin ``b``, so
#: ``[_EXT_BELOW[bin(lo)], _EXT_UPTO[bin(hi)])`` holds every slot in ``[lo, hi]`` (a few
#: more, maybe) and ``[_EXT_UPTO[bin(lo)], _EXT_BELOW[bin(hi)])`` only slots inside it;
#: ``_NEAR_LO[b]`` / ``_NEAR_HI[b]`` is the slot within ``3 * _ANGLE_MARGIN`` below / above
#: bin ``b`` (or in it, or one bin beyond, for rounding), -1 if none (slots are 0.35 rad apart).
_EXT_LO = -4.0 * math.pi
_EXT_BIN = 1.0 / 1024.0
_EXT_NBINS = int(8.0 * math.pi / _EXT_BIN) + 1
_EXT_EDGES = _EXT_LO + _EXT_BIN * np.arange(_EXT_NBINS + 1)
_EXT_BELOW = np.searchsorted(_EXT, _EXT_EDGES[:-1], "left")
_EXT_UPTO = np.searchsorted(_EXT, _EXT_EDGES[1:], "left")
_NEAR_LO = np.full(_EXT_NBINS, -1, dtype=np.int64)
_NEAR_HI = np.full(_EXT_NBINS, -1, dtype=np.int64)
for _s, _v in enumerate(_EXT.tolist()):
    _b = int((_v - _EXT_LO) / _EXT_BIN)
    _NEAR_LO[max(_b - 1, 0) : int((_v + 3.0 * _ANGLE_MARGIN - _EXT_LO) / _EXT_BIN) + 2] = _s
    _NEAR_HI[max(int((_v - 3.0 * _ANGLE_MARGIN - _EXT_LO) / _EXT_BIN) - 1, 0) : _b + 2] = _s
_EMPTY_INT = np.zeros(0, dtype=np.int64)
#: ``_BIT[j] = 1 << j``; ``_FIRST_FREE[side + 1, mask]``: the index in ``OFFSETS`` of the first
#: offset in the order ``_ORDERS[side + 1]`` whose sorted position is not set in ``mask``, -1
#: if every one is.
_BIT = np.left_shift(1, np.arange(OFFSETS.size, dtype=np.int64))
_FIRST_FREE = np.full((3, 1 << OFFSETS.size), -1, dtype=np.int64)
for _i, _order in enumerate(_ORDERS):
    _free = ((np.arange(1 << OFFSETS.size)[:, None] >> _SORTED_POS[_order][None, :]) & 1) == 0
    _FIRST_FREE[_i] = np.where(_free.any(axis=1), _order[_free.argmax(axis=1)], -1)


def _ext_bin(angle: np.ndarray) -> np.ndarray:
    """Bin of ``angle`` (rad, within [-4 pi, 4 pi]) in the ``_EXT_*`` tables."""
    b = ((angle - _EXT_LO) * (1.0 / _EXT_BIN)).astype(np.int64)
    return np.minimum(np.maximum(b, 0, out=b), _EXT_NBINS - 1, out=b)


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


def _pair_gaps(along: np.ndarray, lateral: np.ndarray, contact: float) -> np.ndarray:
    """:func:`corridor_gaps` of pairs already known to be ahead in the corridor."""
    inner = along - np.sqrt(np.maximum(contact * contact - lateral * lateral, 0.0))
    return np.maximum(0.0, np.where(lateral >= contact, along - contact, inner))


class Avoidance:
    """Corridor checks and detour search over the fleet's :class:`~sim.state.FleetState`,
    its neighbor pairs and the static footprint grid, for robots of ``radius`` m."""

    def __init__(
        self, state: FleetState, pairs: NeighborPairs, footprints: FootprintGrid, radius: float
    ) -> None:
        self.state = state
        self.pairs = pairs
        self.footprints = footprints
        self.radius = radius
        self.contact = contact = 2.0 * radius
        self.lat = lat = contact + CORRIDOR_MARGIN_M
        #: the closed-form judgement of detour headings (:meth:`_blocks`) holds when the
        #: corridor is narrower than the detour clearance; pairs are judged that way unless
        #: their distance is within _DIST_MARGIN of where the blocked intervals change shape
        #: (a table over the distance, conservative by a bin on either side)
        self._judged: np.ndarray | None = None
        if 0.0 < contact and lat < AVOID_CLEAR_M and lat < math.hypot(contact, AVOID_CLEAR_M):
            reach_d = math.hypot(AVOID_CLEAR_M + contact, lat)
            lo = (np.arange(int(reach_d / _JUDGED_BIN) + 3) - 1.0) * _JUDGED_BIN
            hi = lo + 3.0 * _JUDGED_BIN
            judged = lo > _DIST_MARGIN
            for crit in (lat, math.hypot(contact, AVOID_CLEAR_M), contact + AVOID_CLEAR_M):
                judged &= (hi < crit - _DIST_MARGIN) | (lo > crit + _DIST_MARGIN)
            self._judged = judged

    def corridor_free(
        self, idx: np.ndarray, hx: np.ndarray, hy: np.ndarray, cap: np.ndarray, obst: np.ndarray
    ) -> np.ndarray:
        """For robots ``idx`` (increasing indices) heading along unit ``(hx, hy)`` (arrays over
        ``idx``): distance (m) to the first robot or dynamic obstacle (rows ``(x, y, radius)``
        of ``obst``) in the corridor ahead, capped at ``cap`` (an array over ``idx``).

        Works on every neighbor pair at once: a robot outside ``idx`` gets the heading
        ``(0, 0)``, so nothing is ahead of it and its pairs find nothing."""
        s = self.state
        n = s.n
        contact, lat = self.contact, self.lat
        reach = math.hypot(float(cap.max()) + contact, lat)
        a, dx, dy, _ = self.pairs.within(reach)
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
        if a.size:
            hxa = hxf[a]
            hya = hyf[a]
            along = dx * hxa + dy * hya
            lateral = np.abs(dx * hya - dy * hxa)
            # only what is ahead, in the corridor and closer than the cap can limit
            hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < capf[a] + contact))
            if hit.size:
                np.minimum.at(best, a[hit], _pair_gaps(along[hit], lateral[hit], contact))
        if idx.size != n:
            best = best[idx]
        if obst.size:
            sx = s.x[idx]
            sy = s.y[idx]
            for qx, qy, qr in obst.tolist():
                best = np.minimum(best, corridor_gaps(qx - sx, qy - sy, hx, hy, self.radius + qr, best))
        return best

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
        self._pair_blocks(fb, db, blocked)
        if obst.size:
            blocked |= self._obstacle_blocks(fb, db, obst)
        self._static_blocks(fb, db, blocked)
        out: np.ndarray = _FIRST_FREE[side + 1, blocked]
        return out

    def _pair_blocks(self, fb: np.ndarray, db: np.ndarray, blocked: np.ndarray) -> None:
        """Set the bits of the offsets that neighbors block (see :meth:`_blocks`): sure
        intervals at once, the (pair, heading) combinations left over by the exact test."""
        n = self.state.n
        nb = fb.size
        kk = OFFSETS.size
        contact, lat, cap = self.contact, self.lat, AVOID_CLEAR_M
        a_all, dx_all, dy_all, d2_all = self.pairs.within(math.hypot(cap + contact, lat))
        loc = np.full(n, -1, dtype=np.int64)
        loc[fb] = np.arange(nb)
        a = loc[a_all]
        sel = np.flatnonzero(a >= 0)
        if not sel.size:
            return
        a = a[sel]
        dx = dx_all[sel]
        dy = dy_all[sel]
        d = np.sqrt(d2_all[sel])
        rho = np.arctan2(dy, dx) - db[a]  # bearing of the neighbor from db, in [-2 pi, 2 pi]
        sure, slots_p, slots = self._blocks(d, rho)
        if sure is not None:
            np.bitwise_or.at(blocked, a, sure)
        if not slots.size:
            return
        # the exact corridor test of corridor_free for the (pair, heading) left over
        ap = a[slots_p]
        h = db[ap] + OFFSETS[_EXT_K[slots]]
        hxc, hyc = np.cos(h), np.sin(h)
        dxc = dx[slots_p]
        dyc = dy[slots_p]
        along = dxc * hxc + dyc * hyc
        lateral = np.abs(dxc * hyc - dyc * hxc)
        hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < cap + contact))
        if hit.size:
            gap = _pair_gaps(along[hit], lateral[hit], contact)
            bad = hit[gap < cap]
            np.bitwise_or.at(blocked, ap[bad], np.left_shift(1, slots[bad] % kk))

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

    def _blocks(self, d: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """Which detour offsets the neighbor of each pair blocks, for neighbors at distance
        ``d`` (m) and bearing ``rho`` (rad) relative to the robot's wanted heading. Returns
        ``(sure, pair, slot)``: ``sure[p]`` a bit mask over the sorted offsets that pair ``p``
        certainly blocks (``None`` if no pair was judged this way), and the (pair, slot of
        ``_EXT``) the exact test must still decide.

        With ``c`` the contact distance, ``lat`` the corridor half-width, ``cap`` =
        :data:`AVOID_CLEAR_M` and ``beta`` the angle from the neighbor's bearing to a heading,
        the corridor test blocks the heading iff (``t1 = d cos beta - sqrt(c^2 - d^2 sin^2
        beta)``, the distance at which the robot's disc touches the neighbor's; it grows with
        ``|beta|`` when ``d > c``):

        * ``d < lat``: ``|beta| < pi / 2``;
        * ``lat < d < hypot(c, cap)``: ``|beta| < asin(lat / d)``;
        * ``hypot(c, cap) < d < c + cap``: ``|beta| < acos((d^2 + cap^2 - c^2) / (2 cap d))``
          (where ``t1 = cap``) or ``asin(c / d) <= |beta| < asin(lat / d)`` (the band where
          the neighbor only grazes the corridor, blocked if it is closer than ``c + cap``
          along it, always here);
        * ``d > c + cap``: ``max(asin(c / d), acos((c + cap) / d)) <= |beta| < asin(lat / d)``.

        Offsets farther than :data:`_ANGLE_MARGIN` inside these intervals are blocked, those
        farther outside are not, whatever the rounding of the floats (it is below 1e-14 rad);
        the offsets within the margin of an end, and all offsets in the window of a pair whose
        ``d`` is within :data:`_DIST_MARGIN` of ``0``, ``lat``, ``hypot(c, cap)`` or ``c +
        cap`` (where the intervals change shape or an end moves fast with ``d``), go to the
        exact test (:meth:`_window_slots`, :meth:`_judged_masks`)."""
        if self._judged is not None:
            # a table over d in bins of _JUDGED_BIN m: False near 0, lat, mid and far
            judged = self._judged[
                np.minimum((d * (1.0 / _JUDGED_BIN)).astype(np.int64), self._judged.size - 1)
            ]
            jp = np.flatnonzero(judged)
            xp = np.flatnonzero(~judged)
        else:
            jp = _EMPTY_INT
            xp = np.arange(d.size)
        sure: np.ndarray | None = None
        pairs: list[np.ndarray] = []
        slots: list[np.ndarray] = []
        if xp.size:
            self._window_slots(d, rho, xp, pairs, slots)
        if jp.size:
            sure = self._judged_masks(d, rho, jp, pairs, slots)
        if not pairs:
            return sure, _EMPTY_INT, _EMPTY_INT
        return sure, np.concatenate(pairs), np.concatenate(slots)

    def _window_slots(
        self, d: np.ndarray, rho: np.ndarray, xp: np.ndarray, pairs: list[np.ndarray], slots: list[np.ndarray]
    ) -> None:
        """Append every (pair, slot) of the pairs ``xp`` in the window where their neighbor can
        be in the corridor at all (all of them get the exact test)."""
        lat = self.lat
        dx_ = d[xp]
        w = np.where(dx_ > lat, np.arcsin(lat / np.maximum(dx_, lat)), 0.5 * math.pi) + _ANGLE_MARGIN
        rx = rho[xp]
        i0 = _EXT_BELOW[_ext_bin(rx - w)]
        cnt = _EXT_UPTO[_ext_bin(rx + w)] - i0
        tot = int(cnt.sum())
        if tot:
            pairs.append(np.repeat(xp, cnt))
            slots.append(np.repeat(i0 - (np.cumsum(cnt) - cnt), cnt) + np.arange(tot))

    def _judged_masks(
        self, d: np.ndarray, rho: np.ndarray, jp: np.ndarray, pairs: list[np.ndarray], slots: list[np.ndarray]
    ) -> np.ndarray:
        """The sure bit masks of all pairs (zero outside ``jp``) from the closed-form intervals
        of the pairs ``jp``; append their (pair, slot) near an interval end for the exact test."""
        contact, lat, cap = self.contact, self.lat, AVOID_CLEAR_M
        mid = math.hypot(contact, cap)
        far = contact + cap
        dj = d[jp]
        b_lat = np.arcsin(np.minimum(lat / dj, 1.0))
        b_c = np.arcsin(np.minimum(contact / dj, 1.0))
        b_t1 = np.arccos(np.minimum((dj * dj + (cap * cap - contact * contact)) / ((2.0 * cap) * dj), 1.0))
        b_along = np.arccos(np.minimum(far / dj, 1.0))
        c1 = dj < lat
        c4 = dj > far
        # central interval |beta| < half (0: none) and band lo <= |beta| < hi (lo >= hi: none)
        half = np.where(c1, 0.5 * math.pi, np.where(dj < mid, b_lat, np.where(c4, 0.0, b_t1)))
        band_lo = np.where(dj > mid, np.where(c4, np.maximum(b_c, b_along), b_c), b_lat + 1.0)
        m = _ANGLE_MARGIN
        inv = 1.0 / _EXT_BIN
        centre = (rho[jp] - _EXT_LO) * inv
        # a band down to nothing still gets its ends tested (it may hold an offset exactly)
        has_c = half > 0.0
        has_b = band_lo < b_lat + 2.0 * m
        # the three intervals in the angle of _EXT: the centre and the band on both sides;
        # the slots strictly inside by the margin (and the bin) are sure, the slots near
        # either end (by _NEAR_LO / _NEAR_HI) go to the exact test
        valid = np.stack((has_c, has_b, has_b))
        b0 = (centre + (np.stack((-half, band_lo, -b_lat)) + m) * inv).astype(np.int64)
        b1 = (centre + (np.stack((half, b_lat, -band_lo)) - m) * inv).astype(np.int64)
        s0 = _EXT_UPTO[b0]
        s1 = np.where(valid, np.maximum(_EXT_BELOW[b1], s0), s0)
        bits = np.left_shift(1, s1) - np.left_shift(1, s0)
        masks = bits[0] | bits[1] | bits[2]
        # fold the three copies of the offsets onto the sorted offsets
        k = OFFSETS.size
        sure: np.ndarray = (masks | (masks >> k) | (masks >> (2 * k))) & ((1 << k) - 1)
        near = np.concatenate((_NEAR_LO[b0], _NEAR_HI[b1]))
        q = np.flatnonzero((near >= 0) & np.concatenate((valid, valid)))
        if q.size:
            pairs.append(jp[q % jp.size])
            slots.append(near.ravel()[q])
        if jp.size != d.size:
            full = np.zeros(d.size, dtype=np.int64)
            full[jp] = sure
            sure = full
        return sure
