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

import heapq
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


@jit
def _relax(
    heap: list[tuple[float, int]],
    cost: np.ndarray,
    parent: np.ndarray,
    n: int,
    cur: int,
    ng: float,
    width: int,
    gx: int,
    gy: int,
    k: float,
) -> None:  # pragma: no cover - compiled
    """:func:`astar`'s step to cell ``n`` from ``cur`` at cost ``ng``: kept and pushed with the
    octile heuristic (weighted 1.001) when cheaper than what ``n`` had."""
    if ng < cost[n]:
        cost[n] = ng
        parent[n] = cur
        ny = n // width
        nx = n - ny * width
        dx = nx - gx if nx > gx else gx - nx
        dy = ny - gy if ny > gy else gy - ny
        heapq.heappush(heap, (ng + 1.001 * (dx + dy + k * (dx if dx < dy else dy)), n))


# long: the planner's A* as written in Python, loop for loop
@jit
def astar(
    free: np.ndarray, width: int, s: int, g: int, sqrt2: float, out: np.ndarray
) -> int:  # pragma: no cover
    """:meth:`sim.planner.GridPlanner._astar` on the padded coarse grid ``free`` (flat, rows
    of ``width`` cells; the border is blocked) from cell ``s`` to cell ``g``: the same search
    (8-connected, no corner cutting, octile heuristic weighted 1.001), the same heap of
    ``(f, cell)`` pairs (``heapq``, ties broken by the cell), so the same path. Writes the
    path's cells from ``s`` to ``g`` into ``out`` and returns how many; 0 when there is none."""
    gy = g // width
    gx = g - gy * width
    size = free.shape[0]
    cost = np.full(size, np.inf)
    parent = np.full(size, -1, dtype=np.int64)
    closed = np.zeros(size, dtype=np.bool_)
    cost[s] = 0.0
    heap = [(0.0, s)]
    straight = (1, -1, width, -width)
    k = sqrt2 - 2.0
    while len(heap):
        cur = heapq.heappop(heap)[1]
        if closed[cur]:
            continue
        if cur == g:
            m = 0
            while cur != -1:
                out[m] = cur
                m += 1
                cur = parent[cur]
            out[:m] = out[:m][::-1].copy()
            return m
        closed[cur] = True
        base = cost[cur]
        for off in straight:
            n = cur + off
            if free[n] and not closed[n]:
                _relax(heap, cost, parent, n, cur, base + 1.0, width, gx, gy, k)
        for d in range(4):
            ox = 1 if d % 2 == 0 else -1
            oy = width if d < 2 else -width
            n = cur + oy + ox
            if free[n] and free[cur + ox] and free[cur + oy] and not closed[n]:
                _relax(heap, cost, parent, n, cur, base + sqrt2, width, gx, gy, k)
    return 0


def warm_up_astar() -> None:
    """Compile (or load from the cache) :func:`astar` with the planner's argument types."""
    free = np.zeros(9, dtype=bool)
    free[4] = True
    astar(free, 3, 4, 4, 2.0**0.5, np.zeros(9, dtype=np.int64))


register_warm_up(warm_up_astar)
