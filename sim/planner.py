"""Global path planning over a static occupancy grid, inflated by the robot radius.

:class:`GridPlanner` is the simulator's stand-in for Nav2's planner server. It plans over
the *static* map only (other robots and dynamic obstacles are left to the reactive safety
layer of :mod:`sim.simulator`), and reports failures with Nav2 Jazzy's planner error codes
(:class:`fleet.types.ErrorCode`), as values, never as exceptions.

Two inflated grids are precomputed with NumPy when the planner is built:

* ``footprint``: cells whose center is within the robot radius of a non-free cell (or of the
  map border). A robot whose center lies in such a cell overlaps an obstacle. The simulator
  uses it to clamp motion and to decide ``START_OCCUPIED`` / ``GOAL_OCCUPIED``.
* ``plan``: the same with ``radius + margin``, the grid paths are searched on, so planned
  paths keep a little clearance.

Planning: a straight segment when it is collision-free on ``footprint``; otherwise A* on a
coarse grid (cells about :data:`COARSE_CELL_M`; 8-connected without corner cutting, octile
heuristic weighted by 1.001 to break ties) whose cells take the value of the fine ``plan``
cell at their center; the cell path is then shortened by line-of-sight checks on the fine
``plan`` grid. Every segment of the result is checked on the ``footprint`` grid (the legs from
the start and to the goal join the coarse grid outside the search, and a thin wall must not be
crossed there); a path that fails the check is ``NO_VALID_PATH``. A* results are cached by
``(start cell, goal cell)`` (the last :data:`PATH_CACHE` used). On a 40 x 30 m map at
0.1 m a plan takes a few milliseconds (about 20 ms in the worst case measured).

Learned obstacles (:meth:`GridPlanner.plan_avoiding`): a robot's costmap adds round obstacles
it has seen (:mod:`sim.costmap`). The static plan is kept when no such disc comes within the
robot radius + :data:`PLAN_MARGIN_M` of it; otherwise the coarse A* runs again (uncached) with
the cells near the discs blocked, and the shortened path keeps the same clearance from them.
A disc that covers the start or the goal is ignored (the robot would otherwise fail to leave
or reach a pose a robot stands on; the reactive safety layer handles that case).

Frame ``map``, units meters.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fleet.maps import FREE, OccupancyGrid
from fleet.types import ErrorCode
from sim import planner_kernels

Point = tuple[float, float]
#: A learned round obstacle: ``(x, y, radius)`` in meters, ``map`` frame.
Disc = tuple[float, float, float]

#: Target size of a coarse A* cell in meters (the fine grid is downsampled to about this).
COARSE_CELL_M = 0.3
#: Clearance added to the robot radius when searching paths, in meters.
PLAN_MARGIN_M = 0.15
#: Plan results kept for repeated requests (oldest dropped first).
RESULT_CACHE = 4096
#: Coarse A* cell paths kept by ``(start cell, goal cell)`` (the least recently used dropped
#: first). A cell path is a few kB; a fleet that keeps driving starts goals from ever new
#: cells, so an unbounded cache grew for as long as the run (docs/performance.md, "Soak").
PATH_CACHE = 1024
_SQRT2 = math.sqrt(2.0)


def inflate(blocked: np.ndarray, radius_cells: float) -> np.ndarray:
    """Return a boolean grid that is True within ``radius_cells`` (cell-center distance) of any
    True cell of ``blocked``; cells outside the array count as blocked (the map border)."""
    h, w = blocked.shape
    r = int(math.floor(radius_cells))
    padded = np.ones((h + 2 * r, w + 2 * r), dtype=bool)
    padded[r : r + h, r : r + w] = blocked
    out = np.zeros((h, w), dtype=bool)
    r2 = radius_cells * radius_cells
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx * dx + dy * dy <= r2:
                out |= padded[r + dy : r + dy + h, r + dx : r + dx + w]
    return out


@dataclass(frozen=True)
class PlanResult:
    """Outcome of one planning request.

    ``path`` is a polyline of ``(x, y)`` points in the ``map`` frame from the start to the
    goal (both included) when ``error_code`` is ``ErrorCode.NONE``; otherwise it is empty and
    ``error_msg`` is a sentence naming the pose that failed.
    """

    path: tuple[Point, ...]
    error_code: ErrorCode = ErrorCode.NONE
    error_msg: str = ""

    @property
    def ok(self) -> bool:
        return self.error_code == ErrorCode.NONE


class GridPlanner:
    """Plans collision-free polylines for a round robot of ``radius`` meters on ``grid``.

    The grid is treated as static: build a new planner if the map changes. ``plan`` never
    raises for an unreachable goal; see :class:`PlanResult`.
    """

    def __init__(
        self, grid: OccupancyGrid, radius: float, margin: float = PLAN_MARGIN_M, compiled: bool = False
    ) -> None:
        self.grid = grid
        #: test segments with the compiled loop (:mod:`sim.planner_kernels`): the same answers
        self.compiled = compiled
        self.radius = float(radius)
        self.margin = float(margin)
        res = grid.resolution
        blocked = grid.cells != FREE
        # A cell is in the footprint if an obstacle cell center is within radius + half a cell
        # (the same rule as OccupancyGrid.is_free).
        self.footprint: np.ndarray = inflate(blocked, radius / res + 0.5)
        self.plan_grid: np.ndarray = inflate(blocked, (radius + margin) / res + 0.5)
        self._fp_list: list[list[bool]] = self.footprint.tolist()
        self._k = max(1, int(round(COARSE_CELL_M / res)))
        k = self._k
        ch = (grid.height + k - 1) // k
        cw = (grid.width + k - 1) // k
        iy = np.minimum(np.arange(ch) * k + k // 2, grid.height - 1)
        ix = np.minimum(np.arange(cw) * k + k // 2, grid.width - 1)
        coarse_free = ~self.plan_grid[np.ix_(iy, ix)]
        self._coarse_free: list[list[bool]] = coarse_free.tolist()
        padded = np.zeros((ch + 2, cw + 2), dtype=bool)
        padded[1:-1, 1:-1] = coarse_free
        self._free_flat: list[bool] = padded.ravel().tolist()
        #: the same cells flat, for the compiled search (:func:`sim.planner_kernels.astar`)
        self._free_arr = padded.ravel()
        #: the same cells as an array, copied for each plan around learned obstacles
        self._free_padded = padded
        self._cw, self._ch = cw, ch
        self._cache: dict[tuple[tuple[int, int], tuple[int, int]], tuple[Point, ...] | None] = {}
        self._results: dict[tuple[float, ...], PlanResult] = {}

    @property
    def cached_paths(self) -> int:
        """Coarse cell paths kept now (at most :data:`PATH_CACHE`)."""
        return len(self._cache)

    # -- cell queries -------------------------------------------------------------------

    def in_map(self, x: float, y: float) -> bool:
        """True if ``(x, y)`` lies inside the map bounds."""
        return self.grid.in_bounds(x, y)

    def footprint_free(self, x: float, y: float) -> bool:
        """True if a robot centered at ``(x, y)`` overlaps no static obstacle and is on the map."""
        g = self.grid
        ix = int(math.floor((x - g.origin_x) / g.resolution))
        iy = int(math.floor((y - g.origin_y) / g.resolution))
        if ix < 0 or iy < 0 or ix >= g.width or iy >= g.height:
            return False
        return not self._fp_list[iy][ix]

    def segment_free(self, a: Point, b: Point, grid: np.ndarray | None = None) -> bool:
        """True if every point of segment ``a``-``b`` is free on ``grid`` (default: the
        planning grid, i.e. radius + margin), sampled every half cell."""
        g = self.grid
        occ = self.plan_grid if grid is None else grid
        length = math.hypot(b[0] - a[0], b[1] - a[1])
        n = max(2, int(math.ceil(length / (0.5 * g.resolution))) + 1)
        if self.compiled:
            free = planner_kernels.segment_cells_free(
                float(a[0]), float(a[1]), float(b[0]), float(b[1]), n, float(g.origin_x),
                float(g.origin_y), float(g.resolution), int(g.width), int(g.height), occ,
            )  # fmt: skip
            return bool(free)
        t = np.linspace(0.0, 1.0, n)
        ix = np.floor((a[0] + t * (b[0] - a[0]) - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((a[1] + t * (b[1] - a[1]) - g.origin_y) / g.resolution).astype(np.int64)
        # t grows from 0 to 1 and every operation above is monotone (rounding included), so
        # the cells' extremes are the ends' cells
        x0, x1, y0, y1 = int(ix[0]), int(ix[-1]), int(iy[0]), int(iy[-1])
        if min(x0, x1) < 0 or min(y0, y1) < 0 or max(x0, x1) >= g.width or max(y0, y1) >= g.height:
            return False
        return not bool(occ[iy, ix].any())

    # -- planning ---------------------------------------------------------------------

    def check_goal(self, x: float, y: float) -> PlanResult | None:
        """Return a failed :class:`PlanResult` if ``(x, y)`` cannot be a goal, else ``None``."""
        if not (math.isfinite(x) and math.isfinite(y)) or not self.in_map(x, y):
            return PlanResult((), ErrorCode.GOAL_OUTSIDE_MAP, f"Goal ({x:.2f}, {y:.2f}) is outside the map.")
        if not self.footprint_free(x, y):
            return PlanResult(
                (),
                ErrorCode.GOAL_OCCUPIED,
                f"Goal ({x:.2f}, {y:.2f}) is occupied: the robot would overlap an obstacle there.",
            )
        return None

    def plan(self, start: Point, goal: Point) -> PlanResult:
        """Plan from ``start`` to ``goal`` (meters, ``map`` frame).

        Error codes: ``START_OUTSIDE_MAP`` / ``START_OCCUPIED`` for a bad start,
        ``GOAL_OUTSIDE_MAP`` / ``GOAL_OCCUPIED`` for a bad goal, ``NO_VALID_PATH`` when the
        free space of the start does not connect to the goal. A plan depends only on its two
        points, so the last :data:`RESULT_CACHE` results for float coordinates are kept and
        returned again for the same points (patrol legs between the same poses).
        """
        key = (*start, *goal)
        # (a key of nonzero floats: -0.0 == 0.0 would hand back the other zero in the path)
        if all(type(v) is float and v != 0.0 for v in key):
            hit = self._results.get(key)
            if hit is None:
                hit = self._plan(start, goal)
                if len(self._results) >= RESULT_CACHE:
                    del self._results[next(iter(self._results))]
                self._results[key] = hit
            return hit
        return self._plan(start, goal)

    def _plan(self, start: Point, goal: Point) -> PlanResult:
        sx, sy = start
        gx, gy = goal
        if not self.in_map(sx, sy):
            return PlanResult(
                (), ErrorCode.START_OUTSIDE_MAP, f"Start ({sx:.2f}, {sy:.2f}) is outside the map."
            )
        if not self.footprint_free(sx, sy):
            return PlanResult(
                (),
                ErrorCode.START_OCCUPIED,
                f"Start ({sx:.2f}, {sy:.2f}) is occupied: the robot overlaps an obstacle.",
            )
        bad = self.check_goal(gx, gy)
        if bad is not None:
            return bad
        if self.segment_free(start, goal, self.footprint):
            return PlanResult((start, goal))
        g = self.grid
        k = self._k
        sc = self._coarse_cell(sx, sy)
        gc = self._coarse_cell(gx, gy)
        key = (sc, gc)
        cache = self._cache
        if key in cache:
            cells = cache[key] = cache.pop(key)  # the most recently used goes last
        else:
            cells = self._astar(sc, gc)
            if len(cache) >= PATH_CACHE:
                del cache[next(iter(cache))]
            cache[key] = cells
        if cells is None:
            return PlanResult(
                (),
                ErrorCode.NO_VALID_PATH,
                f"No valid path from ({sx:.2f}, {sy:.2f}) to goal ({gx:.2f}, {gy:.2f}).",
            )
        half = 0.5 * k * g.resolution
        pts: list[Point] = [start]
        for cx, cy in cells[1:-1]:
            pts.append((g.origin_x + cx * k * g.resolution + half, g.origin_y + cy * k * g.resolution + half))
        pts.append(goal)
        path = self._shorten(pts)
        # the legs to and from the coarse grid are not part of the search: a goal (or start)
        # whose own coarse cell is blocked is joined to the nearest free coarse cell, and that
        # leg must not cross a wall (a thin wall around a small box, for instance)
        for a, b in zip(path, path[1:], strict=False):
            if not self.segment_free(a, b, self.footprint):
                return PlanResult(
                    (),
                    ErrorCode.NO_VALID_PATH,
                    f"No valid path from ({sx:.2f}, {sy:.2f}) to goal ({gx:.2f}, {gy:.2f}).",
                )
        return PlanResult(tuple(path))

    def plan_avoiding(self, start: Point, goal: Point, discs: Sequence[Disc]) -> PlanResult:
        """:meth:`plan` from ``start`` to ``goal`` around the learned round obstacles
        ``discs`` (see the module docstring). ``NO_VALID_PATH`` when they close every way."""
        res = self.plan(start, goal)
        if not res.ok or not discs:
            return res
        clear = self.radius + self.margin
        keep = [
            d
            for d in discs
            if math.hypot(start[0] - d[0], start[1] - d[1]) >= d[2] + self.radius
            and math.hypot(goal[0] - d[0], goal[1] - d[1]) >= d[2] + self.radius
        ]
        if not any(_segment_hits(a, b, keep, clear) for a, b in zip(res.path, res.path[1:], strict=False)):
            return res
        free = self._free_without(keep, clear)
        sc = self._coarse_cell(*start)
        gc = self._coarse_cell(*goal)
        w = self._cw + 2
        for c in (sc, gc):  # the ends stay open (a disc near them is checked on the path)
            free[(c[1] + 1) * w + c[0] + 1] = self._free_flat[(c[1] + 1) * w + c[0] + 1]
        cells = self._astar(sc, gc, free)
        sx, sy = start
        gx, gy = goal
        blocked = PlanResult(
            (),
            ErrorCode.NO_VALID_PATH,
            f"No valid path from ({sx:.2f}, {sy:.2f}) to goal ({gx:.2f}, {gy:.2f}): obstacles in the costmap "
            "block every way.",
        )
        if cells is None:
            return blocked
        g = self.grid
        k = self._k
        half = 0.5 * k * g.resolution
        pts: list[Point] = [start]
        for cx, cy in cells[1:-1]:
            pts.append((g.origin_x + cx * k * g.resolution + half, g.origin_y + cy * k * g.resolution + half))
        pts.append(goal)
        path = self._shorten(pts, keep)
        for a, b in zip(path, path[1:], strict=False):
            if not self.segment_free(a, b, self.footprint) or _segment_hits(a, b, keep, self.radius):
                return blocked
        return PlanResult(tuple(path))

    def _free_without(self, discs: Sequence[Disc], clearance: float) -> np.ndarray:
        """The padded coarse free cells (flat) with the cells within ``r + clearance`` of a disc
        center blocked."""
        g = self.grid
        size = self._k * g.resolution
        free = self._free_padded.copy()
        cx = g.origin_x + (np.arange(self._cw) + 0.5) * size
        cy = g.origin_y + (np.arange(self._ch) + 0.5) * size
        for x, y, r in discs:
            reach = r + clearance + 0.5 * size
            near_x = np.flatnonzero(np.abs(cx - x) <= reach)
            near_y = np.flatnonzero(np.abs(cy - y) <= reach)
            if near_x.size and near_y.size:
                d = np.hypot(cx[near_x][None, :] - x, cy[near_y][:, None] - y)
                yy, xx = np.nonzero(d <= reach)
                free[near_y[yy] + 1, near_x[xx] + 1] = False
        return free.ravel()

    def _coarse_cell(self, x: float, y: float) -> tuple[int, int]:
        """The free coarse cell nearest to ``(x, y)`` (the cell itself if it is free)."""
        g = self.grid
        size = self._k * g.resolution
        cx = min(max(int((x - g.origin_x) // size), 0), self._cw - 1)
        cy = min(max(int((y - g.origin_y) // size), 0), self._ch - 1)
        if self._coarse_free[cy][cx]:
            return (cx, cy)
        best: tuple[float, tuple[int, int]] | None = None
        for r in range(1, 4):
            for dy in range(-r, r + 1):
                for dx in range(-r, r + 1):
                    if max(abs(dx), abs(dy)) != r:
                        continue
                    nx, ny = cx + dx, cy + dy
                    if 0 <= nx < self._cw and 0 <= ny < self._ch and self._coarse_free[ny][nx]:
                        wx = g.origin_x + (nx + 0.5) * size
                        wy = g.origin_y + (ny + 0.5) * size
                        d = math.hypot(wx - x, wy - y)
                        if best is None or d < best[0]:
                            best = (d, (nx, ny))
            if best is not None:
                return best[1]
        return (cx, cy)

    def _astar(
        self, start: tuple[int, int], goal: tuple[int, int], cells: np.ndarray | None = None
    ) -> tuple[tuple[int, int], ...] | None:
        """8-connected A* over the coarse grid (no corner cutting), octile heuristic; ``cells``
        replaces the padded coarse free cells (flat; learned obstacles). Compiled
        (:func:`sim.planner_kernels.astar`) where the planner is: the same search, the same path."""
        W = self._cw + 2
        s = (start[1] + 1) * W + start[0] + 1
        g = (goal[1] + 1) * W + goal[0] + 1
        if self.compiled:
            arr = self._free_arr if cells is None else cells
            if not arr[s] or not arr[g]:
                return None
            found = np.empty(arr.size, dtype=np.int64)
            m = planner_kernels.astar(arr, W, s, g, _SQRT2, found)
            if m == 0:
                return None
            rows, cols = np.divmod(found[:m], W)
            return tuple(zip((cols - 1).tolist(), (rows - 1).tolist(), strict=True))
        free = self._free_flat if cells is None else cells.tolist()
        if not free[s] or not free[g]:
            return None
        gy, gx = divmod(g, W)
        size = len(free)
        cost = [math.inf] * size
        parent = [-1] * size
        closed = bytearray(size)
        cost[s] = 0.0
        heap: list[tuple[float, int]] = [(0.0, s)]
        straight = (1, -1, W, -W)
        diags = ((W + 1, 1, W), (W - 1, -1, W), (-W + 1, 1, -W), (-W - 1, -1, -W))
        k = _SQRT2 - 2.0
        pop, push = heapq.heappop, heapq.heappush
        while heap:
            _, cur = pop(heap)
            if closed[cur]:
                continue
            if cur == g:
                out: list[tuple[int, int]] = []
                while cur != -1:
                    cy, cx = divmod(cur, W)
                    out.append((cx - 1, cy - 1))
                    cur = parent[cur]
                out.reverse()
                return tuple(out)
            closed[cur] = 1
            base = cost[cur]
            for off in straight:
                n = cur + off
                if free[n] and not closed[n]:
                    ng = base + 1.0
                    if ng < cost[n]:
                        cost[n] = ng
                        parent[n] = cur
                        ny, nx = divmod(n, W)
                        dx = nx - gx if nx > gx else gx - nx
                        dy = ny - gy if ny > gy else gy - ny
                        push(heap, (ng + 1.001 * (dx + dy + k * (dx if dx < dy else dy)), n))
            for off, ox, oy in diags:
                n = cur + off
                if free[n] and free[cur + ox] and free[cur + oy] and not closed[n]:
                    ng = base + _SQRT2
                    if ng < cost[n]:
                        cost[n] = ng
                        parent[n] = cur
                        ny, nx = divmod(n, W)
                        dx = nx - gx if nx > gx else gx - nx
                        dy = ny - gy if ny > gy else gy - ny
                        push(heap, (ng + 1.001 * (dx + dy + k * (dx if dx < dy else dy)), n))
        return None

    def _shorten(self, pts: list[Point], discs: Sequence[Disc] = ()) -> list[Point]:
        """Greedy string pulling: from each kept point, jump to the farthest point still in
        sight (and clear of ``discs`` by the planning clearance)."""
        out = [pts[0]]
        i = 0
        n = len(pts)
        clear = self.radius + self.margin
        while i < n - 1:
            j = i + 1
            while (
                j + 1 < n
                and self.segment_free(pts[i], pts[j + 1])
                and not _segment_hits(pts[i], pts[j + 1], discs, clear)
            ):
                j += 1
            out.append(pts[j])
            i = j
        return out


def _segment_hits(a: Point, b: Point, discs: Sequence[Disc], clearance: float) -> bool:
    """True if segment ``a``-``b`` passes closer than ``r + clearance`` to the center of any
    disc ``(x, y, r)`` of ``discs``."""
    ax, ay = a
    ex, ey = b[0] - ax, b[1] - ay
    den = ex * ex + ey * ey
    for x, y, r in discs:
        t = 0.0 if den <= 1e-18 else min(1.0, max(0.0, ((x - ax) * ex + (y - ay) * ey) / den))
        if math.hypot(ax + t * ex - x, ay + t * ey - y) < r + clearance:
            return True
    return False
