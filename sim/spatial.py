"""Neighbor search for many discs at once: a uniform-grid spatial hash in NumPy.

:func:`neighbor_pairs` buckets points into square cells of the query radius
(``floor(pos / radius)``) and sorts them by cell key. Each unordered pair of points in the
same or adjacent cells is then met exactly once, from the point that comes first in a
half-stencil: later points of its own cell and the cell to its right (one range of the sorted
keys), and the three cells of the row above (a second range). The ranges are expanded into
candidate pairs, pairs closer than ``radius`` are kept and returned in both orders. Cost is
O(n log n + pairs); no Python loop runs per point. Frame ``map``, units meters.
"""

from __future__ import annotations

import numpy as np

_EMPTY = np.zeros(0, dtype=np.int64)


def neighbor_pairs(x: np.ndarray, y: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Directed pairs ``(i, j)``, ``i != j``, of points closer than ``radius`` (both orders are
    returned: ``(i, j)`` and ``(j, i)``, each pair once per order). ``x``, ``y`` are 1-D float
    arrays of equal length. The result is deterministic (same input, same arrays); its order
    is not meaningful: the first half holds each unordered pair once, the second half the same
    pairs reversed."""
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
