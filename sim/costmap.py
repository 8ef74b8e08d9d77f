"""Live costmaps of the simulated robots: what each robot has seen, kept and forgotten.

Every robot has two costmaps, as a Nav2 robot does: a **global** one over the whole map (its
planner plans on it) and a **local** rolling window of :data:`LOCAL_SIZE_M` around the robot
(its controller's). Both hold the static map (the ``static`` layer) plus an **obstacle layer**
of round marks learned from the robot's sensor:

* every :data:`SENSE_PERIOD_S` simulated seconds each robot sees, within
  :data:`SENSOR_RANGE_M` and in line of sight over the static map, the dynamic obstacles
  (:meth:`sim.simulator.Simulator.add_obstacle`: boxes, blocked aisles, ...) and the other
  robots that have stood still for :data:`STATIONARY_S` (a broken-down or parked robot; a
  moving robot leaves no mark, as Nav2's raytracing clears the trail of a passing one);
* a mark it sees again is refreshed; a mark in range and in sight whose obstacle has gone is
  cleared (raytrace clearing); a mark not seen for :data:`DECAY_S` decays; local marks outside
  the local window are dropped;
* the clear services clear them (:meth:`Costmaps.clear`, :meth:`Costmaps.clear_region`):
  one costmap or both, everything, everything except a square around the robot, or a square
  around the robot or a pose.

The robot's planner plans around its global marks
(:meth:`sim.planner.GridPlanner.plan_avoiding`), so an aisle a robot has seen blocked is
routed around until the mark is cleared or decays. :meth:`Costmaps.raster` renders a costmap
as Nav2's cost values (254 lethal, 253 inscribed, 0 free) for ``get_costmap``. Marks are
sparse (a dict per robot), so a fleet costs memory only where robots have seen something.

Units m, s; ``map`` frame. No wall clock.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from fleet.maps import FREE, OccupancyGrid
from sim.planner import Disc, inflate
from sim.spatial import neighbor_pairs

#: The robots look around this often (simulated s).
SENSE_PERIOD_S = 0.5
#: How far a robot's sensor sees (m, center to center).
SENSOR_RANGE_M = 2.5
#: A robot standing still (moved less than :data:`STILL_M`) this long is an obstacle to others.
STATIONARY_S = 5.0
#: Motion (m) under which a robot counts as standing still between two looks.
STILL_M = 0.05
#: A mark not seen again for this long is forgotten (s).
DECAY_S = 30.0
#: Width of the local costmap's square window (m), centered on the robot.
LOCAL_SIZE_M = 5.0
#: Nav2's cost values.
LETHAL = 254
INSCRIBED = 253


class Layer(enum.StrEnum):
    """Which of a robot's costmaps: ``global``, ``local`` or ``both``."""

    GLOBAL = "global"
    LOCAL = "local"
    BOTH = "both"

    @classmethod
    def parse(cls, value: str) -> Layer:
        try:
            return cls(value)
        except ValueError:
            raise ValueError(
                f"costmap must be one of {', '.join(v.value for v in cls)}, got {value!r}"
            ) from None


@dataclass(slots=True)
class Mark:
    """A learned obstacle: a disc at ``(x, y)`` of ``r`` meters, last seen at ``seen`` (s);
    ``source`` names it (``"obstacle 3"``, ``"robot /robot2"``)."""

    x: float
    y: float
    r: float
    seen: float
    source: str


@dataclass
class RobotCostmaps:
    """One robot's two obstacle layers (marks by source)."""

    global_marks: dict[str, Mark] = field(default_factory=dict)
    local_marks: dict[str, Mark] = field(default_factory=dict)

    def layers(self, which: Layer) -> list[dict[str, Mark]]:
        if which is Layer.GLOBAL:
            return [self.global_marks]
        if which is Layer.LOCAL:
            return [self.local_marks]
        return [self.global_marks, self.local_marks]


@dataclass(frozen=True)
class CostmapRaster:
    """A costmap rendered as Nav2 costs: ``cost[row, col]`` (uint8, row 0 at ``origin_y``),
    ``resolution`` m per cell, cell (0, 0) at ``(origin_x, origin_y)`` in ``map``."""

    cost: np.ndarray
    origin_x: float
    origin_y: float
    resolution: float


class Costmaps:
    """The costmaps of every robot of a simulator (see the module docstring).

    Args:
        grid: the static map; ``radius``: the robots' radius (m, the inscribed radius).
        compiled: find the robots in sensor range with the compiled neighbor search
            (:func:`sim.spatial.neighbor_pairs`: the same pairs in the same order).
    """

    def __init__(self, grid: OccupancyGrid, radius: float, compiled: bool = False) -> None:
        self.grid = grid
        self.radius = float(radius)
        self.compiled = compiled
        self._blocked = grid.cells != FREE
        self.robots: list[RobotCostmaps] = []
        #: each robot's position when it last moved (rows x, y) and since when it stands (row 2)
        self._still = np.zeros((3, 16))
        #: robots holding marks in either layer (and some whose marks were cleared since)
        self._holders: set[int] = set()
        self._next_sense = 0.0
        self._static_cost: np.ndarray | None = None
        self._names: list[str] = []
        #: Marks learned (counted once per new mark) and cleared by observation.
        self.learned = 0
        self.cleared_by_sight = 0

    def add(self, name: str, x: float, y: float, now: float) -> None:
        """A robot ``name`` (its namespace) added at ``(x, y)``; its costmaps start empty."""
        k = len(self.robots)
        self.robots.append(RobotCostmaps())
        self._names.append(name)
        if k == self._still.shape[1]:
            grown = np.zeros((3, 2 * k))
            grown[:, :k] = self._still
            self._still = grown
        self._still[:, k] = (x, y, now)

    # -- sensing ------------------------------------------------------------------------

    def sense(
        self, now: float, x: np.ndarray, y: np.ndarray, obstacles: dict[int, tuple[float, float, float]]
    ) -> None:
        """Let every robot (at ``x``, ``y``) look around, if a look is due at ``now``;
        ``obstacles`` are the dynamic obstacles by id. See the module docstring."""
        if now < self._next_sense - 1e-9:
            return
        self._next_sense = now + SENSE_PERIOD_S
        n = int(x.shape[0])
        if n == 0:
            return
        stationary = self._stationary(now, x, y)
        seen: dict[int, dict[str, Mark]] = {}
        if obstacles:
            ids = list(obstacles)
            ob = np.array([obstacles[k] for k in ids], dtype=float).reshape(-1, 3)
            d = np.hypot(x[:, None] - ob[None, :, 0], y[:, None] - ob[None, :, 1])
            ii, kk = np.nonzero(d <= SENSOR_RANGE_M + ob[None, :, 2])
            ok = self._in_sight(x[ii], y[ii], ob[kk, 0], ob[kk, 1], ob[kk, 2])
            for i, k in zip(ii[ok].tolist(), kk[ok].tolist(), strict=True):
                src = f"obstacle {ids[k]}"
                seen.setdefault(i, {})[src] = Mark(
                    float(ob[k, 0]), float(ob[k, 1]), float(ob[k, 2]), now, src
                )
        if stationary.any() and n > 1:
            pi, pj = neighbor_pairs(x, y, SENSOR_RANGE_M, self.compiled)
            sel = np.flatnonzero(stationary[pj])
            if sel.size:
                pi, pj = pi[sel], pj[sel]
                ok = self._in_sight(x[pi], y[pi], x[pj], y[pj], np.full(pi.size, self.radius))
                for i, j in zip(pi[ok].tolist(), pj[ok].tolist(), strict=True):
                    src = f"robot {self._names[j]}"
                    seen.setdefault(i, {})[src] = Mark(float(x[j]), float(y[j]), self.radius, now, src)
        for i, marks in seen.items():
            cm = self.robots[i]
            self._holders.add(i)
            for src, m in marks.items():
                if src not in cm.global_marks:
                    self.learned += 1
                cm.global_marks[src] = m
                cm.local_marks[src] = Mark(m.x, m.y, m.r, m.seen, m.source)
        self._forget(now, x, y, seen)

    def _stationary(self, now: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Which robots have stood still for :data:`STATIONARY_S` (bookkeeping per look)."""
        n = int(x.shape[0])
        sx, sy, since = self._still[0, :n], self._still[1, :n], self._still[2, :n]
        moved = np.hypot(x - sx, y - sy) > STILL_M
        sx[moved] = x[moved]
        sy[moved] = y[moved]
        since[moved] = now
        out: np.ndarray = (now - since) >= STATIONARY_S - 1e-9
        return out

    def _in_sight(
        self,
        ax: np.ndarray,
        ay: np.ndarray,
        bx: np.ndarray,
        by: np.ndarray,
        r: np.ndarray,
        samples: int | None = None,
    ) -> np.ndarray:
        """For each pair: no static obstacle cell between the sensor at ``a`` and the near
        edge of the disc of radius ``r`` at ``b``, sampled at ``samples`` points along the way
        (default: every half cell of the longest way of the batch, :meth:`_samples`)."""
        if ax.size == 0:
            return np.zeros(0, dtype=bool)
        g = self.grid
        dx, dy = bx - ax, by - ay
        length = np.hypot(dx, dy)
        reach = np.maximum(length - r, 0.0)
        k = self._samples(float(reach.max())) if samples is None else samples
        t = np.linspace(0.0, 1.0, k)[None, :]
        scale = np.where(length > 1e-9, reach / np.maximum(length, 1e-9), 0.0)[:, None]
        px = ax[:, None] + dx[:, None] * scale * t
        py = ay[:, None] + dy[:, None] * scale * t
        ix = np.floor((px - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((py - g.origin_y) / g.resolution).astype(np.int64)
        inside = (ix >= 0) & (iy >= 0) & (ix < g.width) & (iy < g.height)
        hit = np.zeros(ix.shape, dtype=bool)
        hit[inside] = self._blocked[iy[inside], ix[inside]]
        out: np.ndarray = ~hit.any(axis=1) & inside.all(axis=1)
        return out

    def _samples(self, reach: float) -> int:
        """Points sampled along a line of sight of ``reach`` m (every half cell, at least 2)."""
        return max(int(math.ceil(reach / (0.5 * self.grid.resolution))) + 1, 2)

    # long: one pass gathering every robot's marks, one batched sight test, one pass applying
    def _forget(self, now: float, x: np.ndarray, y: np.ndarray, seen: dict[int, dict[str, Mark]]) -> None:
        """Raytrace clearing, decay and the local window, for robots that hold marks.

        Each layer's look (its marks in range and not seen now) is sampled as if tested on
        its own (:meth:`_samples` of the layer's longest way), but all looks are tested in a
        few batched :meth:`_in_sight` calls, one per sample count."""
        half = 0.5 * LOCAL_SIZE_M
        layers: list[tuple[dict[str, Mark], bool, list[str], list[str]]] = []
        rx_l: list[float] = []
        ry_l: list[float] = []
        mx_l: list[float] = []
        my_l: list[float] = []
        mr_l: list[float] = []
        owner: list[int] = []
        robots = self.robots
        hypot = math.hypot
        none: dict[str, Mark] = {}
        for i in sorted(self._holders):  # the others hold no marks
            cm = robots[i]
            if not cm.global_marks and not cm.local_marks:
                continue
            fresh = seen.get(i, none)
            rx, ry = float(x[i]), float(y[i])
            for marks, local in ((cm.global_marks, False), (cm.local_marks, True)):
                k = len(layers)
                gone: list[str] = []
                look: list[str] = []  # in range and in sight, but not seen now: gone (or moved)?
                for src, m in marks.items():
                    mx, my = m.x, m.y
                    if now - m.seen > DECAY_S or (local and (abs(mx - rx) > half or abs(my - ry) > half)):
                        gone.append(src)
                    if src not in fresh and hypot(mx - rx, my - ry) <= SENSOR_RANGE_M:
                        look.append(src)
                        rx_l.append(rx)
                        ry_l.append(ry)
                        mx_l.append(mx)
                        my_l.append(my)
                        mr_l.append(m.r)
                        owner.append(k)
                layers.append((marks, local, gone, look))
        if owner:
            visible = self._sight_by_layer(rx_l, ry_l, mx_l, my_l, mr_l, np.array(owner), len(layers))
            o = 0
            for _, local, gone, look_src in layers:
                cleared = [
                    src for src, vis in zip(look_src, visible[o : o + len(look_src)], strict=True) if vis
                ]
                o += len(look_src)
                if not local:
                    self.cleared_by_sight += len(cleared)
                gone.extend(cleared)
        for marks, _, gone, _ in layers:
            for src in set(gone):
                marks.pop(src, None)
        self._holders = {i for i in self._holders if robots[i].global_marks or robots[i].local_marks}

    def _sight_by_layer(
        self,
        rx: list[float],
        ry: list[float],
        mx: list[float],
        my: list[float],
        mr: list[float],
        owner: np.ndarray,
        n_layers: int,
    ) -> list[bool]:
        """:meth:`_in_sight` of the looks (sensor ``rx, ry``, mark ``mx, my, mr``), each
        sampled with the sample count of its layer ``owner`` (the layer's longest way)."""
        ax, ay, bx, by, r = (np.array(v) for v in (rx, ry, mx, my, mr))
        reach = np.maximum(np.hypot(bx - ax, by - ay) - r, 0.0)
        longest = np.zeros(n_layers)
        np.maximum.at(longest, owner, reach)
        # as _samples, for every layer at once (the same float division and ceiling)
        half_cell = 0.5 * self.grid.resolution
        counts = np.maximum(np.ceil(longest / half_cell).astype(np.int64) + 1, 2)[owner]
        out = np.zeros(owner.size, dtype=bool)
        for k in np.unique(counts).tolist():
            sel = np.flatnonzero(counts == k)
            out[sel] = self._in_sight(ax[sel], ay[sel], bx[sel], by[sel], r[sel], samples=k)
        visible: list[bool] = out.tolist()
        return visible

    def _static_ring(self) -> np.ndarray:
        """Cells within the robot radius of a static obstacle or the map border (cached)."""
        if self._static_cost is None:
            self._static_cost = inflate(self._blocked, self.radius / self.grid.resolution + 0.5)
        return self._static_cost

    # -- queries and clearing -------------------------------------------------------------

    def marks(self, i: int, which: Layer | str = Layer.GLOBAL) -> list[Mark]:
        """Robot ``i``'s marks in ``which`` costmap (``both``: the union, by source)."""
        out: dict[str, Mark] = {}
        for layer in self.robots[i].layers(Layer.parse(str(which))):
            out.update(layer)
        return list(out.values())

    def discs(self, i: int) -> list[Disc]:
        """Robot ``i``'s global marks as ``(x, y, r)`` discs, for its planner."""
        return [(m.x, m.y, m.r) for m in self.robots[i].global_marks.values()]

    def clear(self, i: int, which: Layer | str = Layer.BOTH) -> int:
        """Clear robot ``i``'s ``which`` costmap(s) entirely; returns the marks removed."""
        n = 0
        for layer in self.robots[i].layers(Layer.parse(str(which))):
            n += len(layer)
            layer.clear()
        return n

    def clear_region(
        self, i: int, which: Layer | str, cx: float, cy: float, reset_distance: float, *, inside: bool
    ) -> int:
        """Clear robot ``i``'s marks whose center lies inside (``inside``) or outside the
        square of side ``reset_distance`` (m) centered on ``(cx, cy)`` (Nav2's
        clear_around / clear_except); returns the marks removed."""
        half = 0.5 * max(0.0, float(reset_distance))
        n = 0
        for layer in self.robots[i].layers(Layer.parse(str(which))):
            drop = [
                src for src, m in layer.items() if (abs(m.x - cx) <= half and abs(m.y - cy) <= half) == inside
            ]
            for src in drop:
                del layer[src]
            n += len(drop)
        return n

    def raster(
        self, i: int, which: Layer | str, rx: float, ry: float, layer: str = "master"
    ) -> CostmapRaster:
        """Robot ``i``'s ``which`` costmap (``global``: the whole map; ``local``: the window
        around ``(rx, ry)``) as Nav2 costs. ``layer``: ``static_layer`` (the map's lethal
        cells), ``obstacle_layer`` (the learned marks), ``inflation_layer`` (the inscribed
        ring of both) or ``master`` (all of them)."""
        g = self.grid
        w = Layer.parse(str(which))
        if w is Layer.BOTH:
            raise ValueError("raster needs one costmap: global or local")
        if w is Layer.GLOBAL:
            x0, y0, c0, r0, cols, rows = g.origin_x, g.origin_y, 0, 0, g.width, g.height
        else:
            cells = int(round(LOCAL_SIZE_M / g.resolution))
            c0 = int(math.floor((rx - g.origin_x) / g.resolution)) - cells // 2
            r0 = int(math.floor((ry - g.origin_y) / g.resolution)) - cells // 2
            cols = rows = cells
            x0, y0 = g.origin_x + c0 * g.resolution, g.origin_y + r0 * g.resolution
        static = np.ones((rows, cols), dtype=bool)  # off the map counts as lethal
        rs, cs = max(r0, 0), max(c0, 0)
        re, ce = min(r0 + rows, g.height), min(c0 + cols, g.width)
        if rs < re and cs < ce:
            static[rs - r0 : re - r0, cs - c0 : ce - c0] = self._blocked[rs:re, cs:ce]
        marks = np.zeros((rows, cols), dtype=bool)
        yy = y0 + (np.arange(rows) + 0.5) * g.resolution
        xx = x0 + (np.arange(cols) + 0.5) * g.resolution
        for m in self.marks(i, w):
            marks |= np.hypot(xx[None, :] - m.x, yy[:, None] - m.y) <= m.r
        lethal = {"static_layer": static, "obstacle_layer": marks}.get(layer, static | marks)
        cost = np.zeros((rows, cols), dtype=np.uint8)
        if layer in ("inflation_layer", "master"):
            r_cells = self.radius / g.resolution + 0.5
            ring_full = np.zeros((rows, cols), dtype=bool)
            if rs < re and cs < ce:
                ring_full[rs - r0 : re - r0, cs - c0 : ce - c0] = self._static_ring()[rs:re, cs:ce]
            cost[ring_full | _dilate(marks, r_cells)] = INSCRIBED
        if layer != "inflation_layer":
            cost[lethal] = LETHAL
        return CostmapRaster(cost, x0, y0, g.resolution)


def _dilate(mask: np.ndarray, radius_cells: float) -> np.ndarray:
    """``mask`` grown by ``radius_cells`` (cell-center distance); outside counts as empty."""
    if not mask.any():
        return mask.copy()
    h, w = mask.shape
    r = int(math.floor(radius_cells))
    padded = np.zeros((h + 2 * r, w + 2 * r), dtype=bool)
    padded[r : r + h, r : r + w] = mask
    out = np.zeros((h, w), dtype=bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx * dx + dy * dy <= radius_cells * radius_cells:
                out |= padded[r + dy : r + dy + h, r + dx : r + dx + w]
    return out
