"""Snapping map poses to SUMO lane points (nearest lane, heading-aware)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fleet.errors import BackendError
from sim.sumo.launch import Libsumo

#: Heading agreement weight when snapping poses to lanes (m of distance per unit of 1-cos).
_HEADING_WEIGHT_M = 0.3
#: Snapped poses remembered (:meth:`LaneIndex.nearest`); the memory is emptied when full.
NEAREST_KEPT = 65536


@dataclass(frozen=True)
class LanePoint:
    """A position on a SUMO lane: ``edge`` id, ``lane`` index, ``pos`` (m from the lane start),
    the snapped point ``(x, y)`` and ``dist`` (m) from the pose it came from."""

    edge: str
    lane: int
    pos: float
    x: float
    y: float
    dist: float


class LaneIndex:
    """Nearest-lane queries over every non-internal lane of the running network (numpy), and
    lane position -> map point.

    Without junction internals SUMO makes a lane as long as its edge's junction-to-junction
    distance but draws it only between the junction borders, so a vehicle would appear to crawl
    along the short drawn lane and jump across the junction. For such straight lanes the index
    uses the *junction-to-junction* line (shifted sideways like the drawn lane) instead: lane
    positions then map linearly onto the roadmap edge, and poses are continuous and accurate.
    Other lanes (curved, or with junction internals) use SUMO's drawn shape.
    """

    def __init__(self, ls: Libsumo) -> None:
        ax: list[float] = []
        ay: list[float] = []
        bx: list[float] = []
        by: list[float] = []
        off: list[float] = []
        scale: list[float] = []
        owner: list[int] = []
        self.lanes: list[tuple[str, int, float]] = []  # (edge, index, length)
        self.edge_length: dict[str, float] = {}
        self.successors: dict[str, list[str]] = {}
        self.lane_count: dict[str, int] = {}
        self._lane_line: dict[tuple[str, int], tuple[list[tuple[float, ...]], float] | None] = {}
        for edge in ls.edge.getIDList():
            if edge.startswith(":"):
                continue
            n = ls.edge.getLaneNumber(edge)
            self.lane_count[edge] = n
            succ: set[str] = set()
            for i in range(n):
                lid = f"{edge}_{i}"
                length = ls.lane.getLength(lid)
                self.edge_length.setdefault(edge, length)
                shape = [tuple(p) for p in ls.lane.getShape(lid)]
                geo = sum(math.dist(a, b) for a, b in zip(shape, shape[1:], strict=False))
                if len(shape) == 2 and geo > 1e-6 and length > geo * 1.01:
                    shape = self._junction_line(ls, edge, shape)
                    geo = math.dist(shape[0], shape[1])
                self._lane_line[(edge, i)] = (shape, length) if len(shape) == 2 else None
                k = length / geo if geo > 1e-9 else 1.0
                acc = 0.0
                li = len(self.lanes)
                for a, b in zip(shape, shape[1:], strict=False):
                    ax.append(a[0])
                    ay.append(a[1])
                    bx.append(b[0])
                    by.append(b[1])
                    off.append(acc)
                    scale.append(k)
                    owner.append(li)
                    acc += math.dist(a, b)
                self.lanes.append((edge, i, length))
                for link in ls.lane.getLinks(lid):
                    to_edge = ls.lane.getEdgeID(link[0])
                    succ.add(to_edge)
            self.successors[edge] = sorted(succ)
        if not ax:
            raise BackendError("the SUMO network has no lanes")
        self._a = np.array([ax, ay]).T
        self._d = np.array([bx, by]).T - self._a
        self._len2 = np.maximum((self._d**2).sum(axis=1), 1e-12)
        self._off = np.array(off)
        self._scale = np.array(scale)
        self._owner = np.array(owner)
        self._heading = np.arctan2(self._d[:, 1], self._d[:, 0])
        self._nearest: dict[tuple[float, float, float | None], LanePoint] = {}

    @staticmethod
    def _junction_line(ls: Libsumo, edge: str, shape: list[tuple[float, ...]]) -> list[tuple[float, ...]]:
        """The junction-centre-to-junction-centre line of ``edge``, shifted sideways by the
        drawn lane's offset from that line."""
        fx, fy = ls.junction.getPosition(ls.edge.getFromJunction(edge))[:2]
        tx, ty = ls.junction.getPosition(ls.edge.getToJunction(edge))[:2]
        dx, dy = tx - fx, ty - fy
        n = math.hypot(dx, dy)
        if n < 1e-6:
            return shape
        ux, uy = dx / n, dy / n
        # signed sideways offset of the drawn lane (left normal = (-uy, ux))
        side = (shape[0][0] - fx) * -uy + (shape[0][1] - fy) * ux
        return [(fx - uy * side, fy + ux * side), (tx - uy * side, ty + ux * side)]

    def point(self, edge: str, lane: int, pos: float) -> tuple[float, float] | None:
        """Map point of lane position ``pos`` (lane units) on a straight lane, else ``None``
        (then ask SUMO: ``simulation.convert2D``)."""
        line = self._lane_line.get((edge, lane))
        if line is None:
            return None
        (a, b), length = line
        f = min(max(pos / length, 0.0), 1.0) if length > 0 else 0.0
        return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]))

    def nearest(self, x: float, y: float, theta: float | None = None) -> LanePoint:
        """The lane point nearest ``(x, y)``; with ``theta``, lanes pointing the pose's way are
        preferred over the opposite lane at a similar distance. A pose snapped before is
        answered from memory (patrols send the same poses again and again; a scan costs
        O(lanes)), the last :data:`NEAREST_KEPT` poses at most."""
        key = (x, y, theta)
        got = self._nearest.get(key)
        if got is None:
            if len(self._nearest) >= NEAREST_KEPT:
                self._nearest.clear()
            got = self._nearest[key] = self._scan(x, y, theta)
        return got

    def _scan(self, x: float, y: float, theta: float | None) -> LanePoint:
        """:meth:`nearest` by testing every lane segment."""
        p = np.array([x, y])
        t = np.clip(((p - self._a) * self._d).sum(axis=1) / self._len2, 0.0, 1.0)
        q = self._a + self._d * t[:, None]
        dist = np.hypot(q[:, 0] - x, q[:, 1] - y)
        cost = dist
        if theta is not None and math.isfinite(theta):
            cost = dist + _HEADING_WEIGHT_M * (1.0 - np.cos(self._heading - theta)) / 2.0
        i = int(np.argmin(cost))
        edge, lane, length = self.lanes[int(self._owner[i])]
        pos = (self._off[i] + t[i] * math.sqrt(self._len2[i])) * self._scale[i]
        return LanePoint(
            edge, lane, float(min(max(pos, 0.0), length)), float(q[i, 0]), float(q[i, 1]), float(dist[i])
        )
