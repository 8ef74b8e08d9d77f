"""Neighbor search for many discs at once: a uniform-grid spatial hash in NumPy.

:func:`neighbor_pairs` buckets points into square cells of the query radius
(``floor(pos / radius)``), sorts them by cell key and, for each of the 3 rows of cells around every
point, expands the sorted range of the 3 adjacent cells into candidate pairs, then keeps pairs closer than ``radius``.
Cost is O(n log n + pairs); no Python loop runs per point. Frame ``map``, units meters.
"""

from __future__ import annotations

import numpy as np

_EMPTY = np.zeros(0, dtype=np.int64)


def neighbor_pairs(x: np.ndarray, y: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Directed pairs ``(i, j)``, ``i != j``, of points closer than ``radius`` (both orders are
    returned: ``(i, j)`` and ``(j, i)``). ``x``, ``y`` are 1-D float arrays of equal length.
    The result is deterministic: sorted by ``i`` and, within ``i``, by cell then index."""
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
    offs = np.array([-w, 0, w], dtype=np.int64)
    q = (key[:, None] + offs[None, :]).ravel()
    lo = np.searchsorted(skey, q - 1, "left")
    hi = np.searchsorted(skey, q + 1, "right")
    cnt = hi - lo
    tot = int(cnt.sum())
    if tot == 0:
        return _EMPTY, _EMPTY
    ii = np.repeat(np.repeat(np.arange(n, dtype=np.int64), 3), cnt)
    start = np.repeat(lo - (np.cumsum(cnt) - cnt), cnt)
    jj = order[np.arange(tot, dtype=np.int64) + start]
    dx = x[jj] - x[ii]
    dy = y[jj] - y[ii]
    keep = (ii != jj) & (dx * dx + dy * dy < radius * radius)
    return ii[keep], jj[keep]
