"""The detour search's blocked headings in one compiled pass (:mod:`sim.kernels`): the
neighbors' corridor test of every (pair, offset) and the static map's footprint samples of
the offsets still free, which :class:`sim.avoidance.Avoidance` otherwise runs as
:func:`sim.kernels.pair_blocks` followed by NumPy passes (``Avoidance._static_blocks``).

Same bits: the headings' cosines and sines are computed once, as ``pair_blocks`` computes
them (the C library's, NumPy's bits), and the static test samples the same points
(``x + cos(h) * d``) on the same padded footprint mask (:meth:`sim.footprint.FootprintGrid.free`);
a robot whose cell is in the clear (:meth:`sim.footprint.FootprintGrid.clear`) is not sampled.
"""

from __future__ import annotations

import numpy as np

from sim.kernels import detour_headings, jit, pair_blocks_along, register_warm_up
from sim.motion_kernels import _free


# long: the pair test and the static samples of every blocked robot and offset, in one pass
@jit
def detour_blocks(
    a_all: np.ndarray,
    dx_all: np.ndarray,
    dy_all: np.ndarray,
    d2_all: np.ndarray,
    reach2: float,
    loc: np.ndarray,
    db: np.ndarray,
    xb: np.ndarray,
    yb: np.ndarray,
    offsets: np.ndarray,
    bits: np.ndarray,
    contact: float,
    lat: float,
    cap: float,
    gx: float,
    gy: float,
    res: float,
    width: int,
    height: int,
    cells: np.ndarray,
    clear_cells: np.ndarray,
    samples: np.ndarray,
    blocked: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`sim.kernels.pair_blocks` (same arguments up to ``cap``; ``xb``, ``yb``: the
    blocked robots' positions, one per ``db``), then for each blocked robot whose cell is not
    clear (``clear_cells``, the padded clearance mask) and each offset its neighbors left
    free: the bit of the offset is set when a sample ``samples[j]`` m along the heading puts
    the footprint off the free cells (``cells``, the padded grid of ``width`` x ``height``
    cells of ``res`` m from ``(gx, gy)``)."""
    nb = db.shape[0]
    kk = offsets.shape[0]
    hx, hy = detour_headings(db, offsets)
    pair_blocks_along(a_all, dx_all, dy_all, d2_all, reach2, loc, hx, hy, bits, contact, lat, cap, blocked)
    ns = samples.shape[0]
    for r in range(nb):
        x = xb[r]
        y = yb[r]
        if _free(x, y, gx, gy, res, width, height, clear_cells):
            continue
        m = blocked[r]
        for k in range(kk):
            if m & bits[k]:
                continue
            for j in range(ns):
                if not _free(
                    x + hx[r, k] * samples[j], y + hy[r, k] * samples[j], gx, gy, res, width, height, cells
                ):
                    m |= bits[k]
                    break
        blocked[r] = m


def warm_up() -> None:
    """Compile (or load from the cache) :func:`detour_blocks` with the detour's argument types."""
    ints = np.zeros(0, dtype=np.int64)
    f = np.zeros(0)
    cells = np.zeros(9, dtype=bool)
    detour_blocks(
        ints, f, f, f, 1.0, ints, f, f, f, np.zeros(1), np.ones(1, dtype=np.int64), 0.6, 0.65, 0.8,
        0.0, 0.0, 0.1, 1, 1, cells, cells, np.zeros(1), ints,
    )  # fmt: skip


register_warm_up(warm_up)
