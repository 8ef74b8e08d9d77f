"""Where a robot's round footprint fits on the static map, for many positions at once.

:class:`FootprintGrid` answers, element-wise over arrays of robot centers (``map`` frame, m),
whether the footprint overlaps no static obstacle and stays on the map (:meth:`free`), and
whether no blocked footprint cell lies within a clearance radius (:meth:`clear`: every detour
sample of a robot there is free, so the detour search can skip its static checks).
"""

from __future__ import annotations

import math

import numpy as np

from fleet.maps import OccupancyGrid
from sim.planner import inflate


class FootprintGrid:
    """The planner's ``footprint`` grid (True where a robot center would overlap an obstacle)
    padded with a blocked border, so positions off the map are not free.

    Args:
        grid: the static map.
        footprint: boolean cells of ``grid``, True where a robot center is not allowed.
        clear_m: the clearance (m) of :meth:`clear` and the reach of :attr:`samples`.
    """

    def __init__(self, grid: OccupancyGrid, footprint: np.ndarray, clear_m: float) -> None:
        self.grid = grid
        self._footprint = footprint
        self._clear_m = clear_m
        padded = np.zeros((grid.height + 2, grid.width + 2), dtype=bool)
        padded[1:-1, 1:-1] = ~footprint
        #: the padded free mask, flat: cell ``(iy, ix)`` (``-1 .. height``, ``-1 .. width``) is
        #: at ``(iy + 1) * (width + 2) + ix + 1``
        self.cells = padded.ravel()
        self._clear: np.ndarray | None = None
        samples: list[float] = []
        stepd = 0.5 * grid.resolution
        sd = stepd
        while sd <= clear_m:
            samples.append(sd)
            sd += stepd
        #: distances (m) every half cell up to ``clear_m``: where a straight move is sampled
        self.samples = np.array(samples)

    def free(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where a robot centered at ``(x, y)`` overlaps no static obstacle and is on the
        map (element-wise)."""
        g = self.grid
        ix = np.floor((x - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((y - g.origin_y) / g.resolution).astype(np.int64)
        np.minimum(np.maximum(ix, -1, out=ix), g.width, out=ix)
        np.minimum(np.maximum(iy, -1, out=iy), g.height, out=iy)
        iy += 1
        iy *= g.width + 2
        iy += ix
        iy += 1
        out: np.ndarray = self.cells[iy]
        return out

    def clear(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where the cell of ``(x, y)`` has no blocked footprint cell (nor the map edge)
        within ``clear_m`` + a cell diagonal (center to center). Built on first use."""
        g = self.grid
        clear = self.clear_cells()
        ix = np.floor((x - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((y - g.origin_y) / g.resolution).astype(np.int64)
        np.minimum(np.maximum(ix, -1, out=ix), g.width, out=ix)
        np.minimum(np.maximum(iy, -1, out=iy), g.height, out=iy)
        out: np.ndarray = clear[(iy + 1) * (g.width + 2) + ix + 1]
        return out

    def clear_cells(self) -> np.ndarray:
        """The padded mask :meth:`clear` reads (flat, laid out as :attr:`cells`): True where no
        blocked footprint cell lies within ``clear_m`` + a cell diagonal. Built on first use."""
        if self._clear is None:
            g = self.grid
            radius_cells = self._clear_m / g.resolution + math.sqrt(2.0) + 1e-3
            blocked = inflate(self._footprint, radius_cells)
            padded = np.zeros((g.height + 2, g.width + 2), dtype=bool)
            padded[1:-1, 1:-1] = ~blocked
            self._clear = padded.ravel()
        return self._clear
