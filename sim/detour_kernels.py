"""The detour search's blocked headings in one compiled pass (:mod:`sim.kernels`): the
neighbors' corridor test of every (pair, offset) and the static map's footprint samples of
the offsets still free, which :class:`sim.avoidance.Avoidance` otherwise runs as
:func:`sim.kernels.pair_blocks` followed by NumPy passes (``Avoidance._static_blocks``).

Same bits: the headings' cosines and sines are computed as ``pair_blocks`` computes them (the
C library's, NumPy's bits), or taken from the robot's row of a cache kept between steps when
its wanted heading is the very same float as when the row was computed (about 3 in 10 blocked
robots a step in a jam; :func:`cached_headings`), and the static test samples the same points
(``x + cos(h) * d``) on the same padded footprint mask (:meth:`sim.footprint.FootprintGrid.free`);
a robot whose cell is in the clear (:meth:`sim.footprint.FootprintGrid.clear`) is not sampled.
"""

from __future__ import annotations

import math

import numpy as np

from sim.kernels import jit, pair_blocks_along, register_warm_up
from sim.motion_kernels import _free


@jit
def cached_headings(
    fb: np.ndarray,
    db: np.ndarray,
    offsets: np.ndarray,
    c_db: np.ndarray,
    c_ok: np.ndarray,
    c_hx: np.ndarray,
    c_hy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`sim.kernels.detour_headings` of the robots ``fb`` (row ``r`` for robot ``fb[r]``
    heading for ``db[r]``), through a cache by robot: ``c_db[i]`` the heading whose unit
    vectors ``c_hx[i]``, ``c_hy[i]`` hold (valid where ``c_ok[i]``). A row is reused only
    when its heading has the very bits of ``db[r]`` (equal, and the same sign of a zero), so
    the vectors are the bits a fresh ``cos`` / ``sin`` would give; else computed and stored."""
    nb = db.shape[0]
    kk = offsets.shape[0]
    hx = np.empty((nb, kk))
    hy = np.empty((nb, kk))
    for r in range(nb):
        i = fb[r]
        h0 = db[r]
        if c_ok[i] and c_db[i] == h0 and math.copysign(1.0, c_db[i]) == math.copysign(1.0, h0):
            for k in range(kk):
                hx[r, k] = c_hx[i, k]
                hy[r, k] = c_hy[i, k]
            continue
        for k in range(kk):
            h = h0 + offsets[k]
            c = math.cos(h)
            sn = math.sin(h)
            hx[r, k] = c
            hy[r, k] = sn
            c_hx[i, k] = c
            c_hy[i, k] = sn
        c_db[i] = h0
        c_ok[i] = True
    return hx, hy


# long: the pair test and the static samples of every blocked robot and offset, in one pass
@jit
def detour_blocks(
    fb: np.ndarray,
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
    c_db: np.ndarray,
    c_ok: np.ndarray,
    c_hx: np.ndarray,
    c_hy: np.ndarray,
    blocked: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`sim.kernels.pair_blocks` (same arguments from ``a_all`` up to ``cap``; ``fb``:
    the blocked robots, one per ``db``, whose headings' vectors come through the cache
    ``c_db`` .. ``c_hy`` of :func:`cached_headings`; ``xb``, ``yb``: the
    blocked robots' positions, one per ``db``), then for each blocked robot whose cell is not
    clear (``clear_cells``, the padded clearance mask) and each offset its neighbors left
    free: the bit of the offset is set when a sample ``samples[j]`` m along the heading puts
    the footprint off the free cells (``cells``, the padded grid of ``width`` x ``height``
    cells of ``res`` m from ``(gx, gy)``)."""
    nb = db.shape[0]
    kk = offsets.shape[0]
    hx, hy = cached_headings(fb, db, offsets, c_db, c_ok, c_hx, c_hy)
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
        ints, ints, f, f, f, 1.0, ints, f, f, f, np.zeros(1), np.ones(1, dtype=np.int64), 0.6, 0.65, 0.8,
        0.0, 0.0, 0.1, 1, 1, cells, cells, np.zeros(1), f, np.zeros(0, dtype=bool), np.zeros((0, 1)),
        np.zeros((0, 1)), ints,
    )  # fmt: skip


register_warm_up(warm_up)
