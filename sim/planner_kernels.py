"""The planner's segment test as one compiled loop (:mod:`sim.kernels`).

:meth:`sim.planner.GridPlanner.segment_free` samples a segment every half cell and asks
whether every sample's cell is free. Its NumPy code builds the samples with ``np.linspace``
and four array passes, which costs more than the test for the short segments a plan is made
of (a plan around learned obstacles tests about 20 of them). :func:`segment_cells_free` walks
the same samples one by one and stops at the first blocked cell: the same answer, from the
same floats (``linspace``'s ``k * (1 / (n - 1))`` with the last sample exactly 1, then ``a + t
* (b - a)``, minus the origin, divided by the resolution, floored).
"""

from __future__ import annotations

import math

import numpy as np

from sim.kernels import jit, register_warm_up


@jit
def segment_cells_free(
    ax: float,
    ay: float,
    bx: float,
    by: float,
    n: int,
    gx: float,
    gy: float,
    res: float,
    width: int,
    height: int,
    occ: np.ndarray,
) -> bool:  # pragma: no cover - compiled
    """Whether the ``n >= 2`` samples of the segment ``(ax, ay)``-``(bx, by)`` (m, ``map``)
    fall in cells of the ``width`` x ``height`` grid of ``res`` m from ``(gx, gy)`` that are all
    free (``occ[row, col]`` false). False when the end samples' cells leave the grid (the
    cells of the samples between lie within the ends' bounds: every operation is monotone)."""
    step = 1.0 / (n - 1)
    ex = bx - ax
    ey = by - ay
    x0 = math.floor((ax + 0.0 * ex - gx) / res)
    y0 = math.floor((ay + 0.0 * ey - gy) / res)
    x1 = math.floor((ax + 1.0 * ex - gx) / res)
    y1 = math.floor((ay + 1.0 * ey - gy) / res)
    if min(x0, x1) < 0 or min(y0, y1) < 0 or max(x0, x1) >= width or max(y0, y1) >= height:
        return False
    for k in range(n):
        t = 1.0 if k == n - 1 else k * step
        ix = math.floor((ax + t * ex - gx) / res)
        iy = math.floor((ay + t * ey - gy) / res)
        if occ[iy, ix]:
            return False
    return True


def warm_up() -> None:
    """Compile (or load from the cache) :func:`segment_cells_free` with the planner's types."""
    segment_cells_free(0.0, 0.0, 0.1, 0.1, 2, 0.0, 0.0, 0.1, 1, 1, np.zeros((1, 1), dtype=bool))


register_warm_up(warm_up)
