"""Neighbor search for many discs at once: a uniform-grid spatial hash in NumPy.

:func:`neighbor_pairs` buckets points into square cells of the query radius
(``floor(pos / radius)``) and sorts them by cell key. Each unordered pair of points in the
same or adjacent cells is then met exactly once, from the point that comes first in a
half-stencil: later points of its own cell and the cell to its right (one range of the sorted
keys), and the three cells of the row above (a second range). The ranges are expanded into
candidate pairs, pairs closer than ``radius`` are kept and returned in both orders. Cost is
O(n log n + pairs); no Python loop runs per point. Frame ``map``, units meters.

:class:`NeighborPairs` keeps the pairs of the simulated fleet that can matter to avoidance,
the safety stop and contacts as a Verlet list over :func:`neighbor_pairs`.
"""

from __future__ import annotations

import numpy as np

from sim import kernels

_EMPTY = np.zeros(0, dtype=np.int64)


def neighbor_pairs(
    x: np.ndarray, y: np.ndarray, radius: float, compiled: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Directed pairs ``(i, j)``, ``i != j``, of points closer than ``radius`` (both orders are
    returned: ``(i, j)`` and ``(j, i)``, each pair once per order). ``x``, ``y`` are 1-D float
    arrays of equal length. The result is deterministic (same input, same arrays); its order
    is not meaningful: the first half holds each unordered pair once, the second half the same
    pairs reversed. ``compiled``: expand the ranges and test the distances in one compiled
    loop (:func:`sim.kernels.cell_pairs`): the same pairs in the same order."""
    n = int(x.shape[0])
    if n < 2:
        return _EMPTY, _EMPTY
    cx = np.floor(x / radius).astype(np.int64)
    cy = np.floor(y / radius).astype(np.int64)
    cx -= cx.min()
    cy -= cy.min()
    w = int(cx.max()) + 3
    key = (cy + 1) * w + (cx + 1)
    order = np.argsort(key, kind="stable")
    skey = key[order]
    pos = np.arange(n, dtype=np.int64)
    # range 1: the rest of my cell and the cell to the right; range 2: the row above
    hi1 = np.searchsorted(skey, skey + 1, "right")
    lo2 = np.searchsorted(skey, skey + (w - 1), "left")
    hi2 = np.searchsorted(skey, skey + (w + 1), "right")
    if compiled:
        tot = int((hi1 - pos - 1).sum() + (hi2 - lo2).sum())
        if tot == 0:
            return _EMPTY, _EMPTY
        a = np.empty(tot, dtype=np.int64)
        b = np.empty(tot, dtype=np.int64)
        k = kernels.cell_pairs(order, hi1, lo2, hi2, x, y, radius * radius, a, b)
        a, b = a[:k], b[:k]
        return np.concatenate((a, b)), np.concatenate((b, a))
    lo = np.concatenate((pos + 1, lo2))
    cnt = np.concatenate((hi1 - pos - 1, hi2 - lo2))
    tot = int(cnt.sum())
    if tot == 0:
        return _EMPTY, _EMPTY
    ii = order[np.repeat(np.concatenate((pos, pos)), cnt)]
    jj = order[np.repeat(lo - (np.cumsum(cnt) - cnt), cnt) + np.arange(tot, dtype=np.int64)]
    dx = x[jj] - x[ii]
    dy = y[jj] - y[ii]
    keep = np.flatnonzero(dx * dx + dy * dy < radius * radius)
    a = ii[keep]
    b = jj[keep]
    return np.concatenate((a, b)), np.concatenate((b, a))


#: The neighbor-pair list is rebuilt every this many steps (with a margin for the motion in
#: between), not every step.
PAIR_REUSE_STEPS = 4


def near_any(
    px: np.ndarray, py: np.ndarray, sites_x: np.ndarray, sites_y: np.ndarray, radius: float
) -> np.ndarray:
    """For each point ``(px[i], py[i])``: whether some site lies within ``radius``
    (``hypot(site - point) <= radius``, the very test of the all-pairs expression
    ``(np.hypot(sx[None, :] - px[:, None], sy[None, :] - py[:, None]) <= radius).any(axis=1)``,
    so the answer is bit-identical). Only the sites whose ``x`` is within ``radius`` (plus a
    margin) of the point are tested (sites sorted by ``x``, one range per point): O((n + m)
    log m + candidates) instead of n x m."""
    n = int(px.shape[0])
    out = np.zeros(n, dtype=bool)
    if n == 0 or sites_x.shape[0] == 0:
        return out
    order = np.argsort(sites_x, kind="stable")
    sx, sy = sites_x[order], sites_y[order]
    margin = radius + 1e-9 * (1.0 + abs(radius))
    lo = np.searchsorted(sx, px - margin, side="left")
    hi = np.searchsorted(sx, px + margin, side="right")
    counts = hi - lo
    total = int(counts.sum())
    if total == 0:
        return out
    owner = np.repeat(np.arange(n), counts)
    starts = np.repeat(lo - np.cumsum(counts) + counts, counts)
    j = starts + np.arange(total)
    hit = np.hypot(sx[j] - px[owner], sy[j] - py[owner]) <= radius
    out[owner[hit]] = True
    return out


class NeighborPairs:
    """The directed neighbor pairs of the fleet and their offsets at the start of the step.

    A Verlet list: the pairs closer than ``radius`` plus what ``PAIR_REUSE_STEPS`` steps of
    motion at ``max_speed`` (m/s) can close, rebuilt every :data:`PAIR_REUSE_STEPS` steps (or
    when a robot was added). Each step :meth:`update` keeps the pairs closer than ``short``
    (m) in a short list (``si``, ``sj``, ``sdx``, ``sdy``, ``sd2``: the offsets ``dx = x[j] -
    x[i]``, ``dy``, ``d2 = dx**2 + dy**2``), in one compiled pass with ``compiled``
    (:func:`sim.kernels.short_pairs`), else with NumPy; the offsets of every pair (``dx``,
    ``dy``, ``d2``) are computed with NumPy on first use in the step when compiled (a compiled
    loop over all pairs reads :meth:`index_pairs` and the positions instead)."""

    def __init__(self, radius: float, short: float, max_speed: float, compiled: bool = False) -> None:
        self.radius = radius
        self.short = short
        self.compiled = compiled
        self._max_speed = max_speed
        self.i = self.j = _EMPTY
        self._dx = self._dy = self._d2 = np.zeros(0)
        self._full = True
        self.si = self.sj = _EMPTY
        self.sdx = self.sdy = self.sd2 = self._d2
        self._n = -1
        self._built = 0
        #: the compiled pass's output arrays, kept while the list keeps its length
        self._floats = np.empty((3, 0))
        self._ints = np.empty((2, 0), dtype=np.int64)
        #: the positions of the step's start (compiled): what every offset is computed from
        self.x0 = self.y0 = self._d2

    @property
    def dx(self) -> np.ndarray:
        """``x[j] - x[i]`` of every pair ``(i, j)`` (m)."""
        self._all_offsets()
        return self._dx

    @property
    def dy(self) -> np.ndarray:
        """``y[j] - y[i]`` of every pair ``(i, j)`` (m)."""
        self._all_offsets()
        return self._dy

    @property
    def d2(self) -> np.ndarray:
        """``dx * dx + dy * dy`` of every pair (m²)."""
        self._all_offsets()
        return self._d2

    def update(self, x: np.ndarray, y: np.ndarray, step: int, dt: float) -> None:
        """Refresh the pairs of the robots at ``(x, y)`` (one entry per robot) for step number
        ``step`` of ``dt`` seconds."""
        n = int(x.shape[0])
        if n != self._n or step - self._built >= PAIR_REUSE_STEPS:
            skin = 2.0 * self._max_speed * dt * PAIR_REUSE_STEPS
            self.i, self.j = neighbor_pairs(x, y, self.radius + skin, self.compiled)
            self._n, self._built = n, step
        pi, pj = self.i, self.j
        if self.compiled:
            self.x0, self.y0 = x.copy(), y.copy()
        if self.compiled and self.short < self.radius:
            m = pi.shape[0]
            if self._floats.shape[1] != m:  # a new list: new buffers, reused until the next
                self._floats = np.empty((3, m))
                self._ints = np.empty((2, m), dtype=np.int64)
            sdx, sdy, sd2 = self._floats
            si, sj = self._ints
            k = kernels.short_pairs(pi, pj, x, y, self.short * self.short, si, sj, sdx, sdy, sd2)
            self.si, self.sj, self.sdx, self.sdy, self.sd2 = si[:k], sj[:k], sdx[:k], sdy[:k], sd2[:k]
            self._full = False
            return
        self._dx = x[pj] - x[pi]
        self._dy = y[pj] - y[pi]
        self._d2 = self._dx * self._dx + self._dy * self._dy
        self._full = True
        if self.short < self.radius:
            near = np.flatnonzero(self._d2 < self.short * self.short)
            self.si, self.sj = pi[near], pj[near]
            self.sdx, self.sdy, self.sd2 = self._dx[near], self._dy[near], self._d2[near]
        else:
            self.si, self.sj, self.sdx, self.sdy, self.sd2 = pi, pj, self._dx, self._dy, self._d2

    def _all_offsets(self) -> None:
        """The offsets of every pair from the step's start positions, once per step (the
        floats of :func:`sim.kernels.short_pairs`: ``x[j] - x[i]``, then ``dx * dx + dy * dy``)."""
        if not self._full:
            pi, pj = self.i, self.j
            self._dx = self.x0[pj] - self.x0[pi]
            self._dy = self.y0[pj] - self.y0[pi]
            self._d2 = self._dx * self._dx + self._dy * self._dy
            self._full = True

    def index_pairs(self, reach: float) -> tuple[np.ndarray, np.ndarray]:
        """``(i, j)`` of a list of directed pairs holding every pair with ``d2 < reach**2``
        (the short list when it reaches that far, else all pairs), for a compiled loop that
        computes the offsets from :attr:`x0`, :attr:`y0` and tests ``d2`` itself."""
        if reach <= self.short:
            return self.si, self.sj
        return self.i, self.j

    def candidates(self, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(i, dx, dy, d2)`` of a list of directed pairs holding every pair with ``d2 <
        reach**2`` (the short list when it reaches that far, else all pairs), unfiltered: for
        a loop that tests ``d2`` itself."""
        if reach <= self.short:
            return self.si, self.sdx, self.sdy, self.sd2
        return self.i, self.dx, self.dy, self.d2

    def within(self, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(i, dx, dy, d2)`` of the directed pairs ``(i, j)`` that can matter to a corridor
        check reaching ``reach`` m: those with ``d2 < reach**2`` (every pair when the reach
        is beyond the pair radius)."""
        if reach >= self.radius:
            return self.i, self.dx, self.dy, self.d2
        if reach <= self.short:
            a, dx, dy, d2 = self.si, self.sdx, self.sdy, self.sd2
        else:
            a, dx, dy, d2 = self.i, self.dx, self.dy, self.d2
        near = np.flatnonzero(d2 < reach * reach)
        if near.size == a.size:
            return a, dx, dy, d2
        return a[near], dx[near], dy[near], d2[near]
