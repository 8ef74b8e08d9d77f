"""Docks: parking spots, chargers and robot start poses joined to the roadmap for traffic.

The traffic manager (:mod:`fleet.traffic`) only lets robots drive along roadmap edges, but
robots start in parking rows and charge at chargers beside the corridors, off the roadmap.
:func:`add_docks` returns a copy of the roadmap graph in which every such pose is a node (a
*dock*) joined to the roadmap by one short edge (a *spur*), so the robots' way in and out
is reserved like any other edge:

* A dock is joined to the nearest point of the roadmap's edges: the foot of the
  perpendicular. If the foot is within ``clearance`` of one of the edge's ends, the spur
  goes to that end; otherwise the edge is split there by a new node (``via:<x>,<y>``; an
  edge's ``length`` is split in proportion), so a spur meets a corridor at right angles.
* If another dock lies within ``clearance`` of that spur (a back-row parking spot behind a
  front-row one), the spur goes to that dock instead, so a robot leaving the back row
  passes through the spot in front (which the manager reserves: it waits, or nudges an
  idle robot there aside). Docks are joined nearest-the-roadmap first, so the dock in
  front is always joined already.
* A dock within ``clearance`` of a roadmap node (or of another dock) *is* that node (no
  spur). A connection that would pass through an obstacle of the map (``grid``, with
  ``radius``) is not used: the next nearest nodes are tried, and a dock that cannot be
  joined raises :class:`DockError`.

Every edge of the result is at least ``clearance`` long, as the manager requires. The
original graph is not modified. Units: meters.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import networkx as nx
import numpy as np

from fleet.errors import DockError
from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.maps import OccupancyGrid

#: How many nearest nodes are tried when the nearest edge point cannot be used.
FALLBACK_NODES = 6


def add_docks(
    graph: nx.Graph[str],
    docks: Sequence[tuple[str, Pose2D]],
    clearance: float,
    grid: OccupancyGrid | None = None,
    radius: float = 0.0,
) -> tuple[nx.Graph[str], dict[str, str]]:
    """The roadmap ``graph`` with every ``(label, pose)`` of ``docks`` joined to it (see the
    module docstring). Returns ``(graph, node_of)`` where ``node_of[label]`` is the node of
    each dock (``dock:<label>``, or the existing node it coincides with). Labels must be
    unique. Raises :class:`DockError` if a dock cannot be joined."""
    g = graph.copy()
    node_of: dict[str, str] = {}
    if not docks:
        return g, node_of
    seen: set[str] = set()
    for label, _ in docks:
        if label in seen:
            raise DockError(f"dock label {label!r} is used twice")
        seen.add(label)
    roads = _EdgeIndex(g)
    xy = np.array([(p.x, p.y) for _, p in docks], dtype=float).reshape(-1, 2)
    order = sorted(range(len(docks)), key=lambda i: (roads.nearest(xy[i, 0], xy[i, 1])[0], i))
    for i in order:
        label, pose = docks[i]
        node_of[label] = _join(g, roads, xy, i, docks, node_of, clearance, grid, radius)
    return g, node_of


def _join(
    g: nx.Graph[str],
    roads: _EdgeIndex,
    xy: np.ndarray,
    i: int,
    docks: Sequence[tuple[str, Pose2D]],
    node_of: dict[str, str],
    clearance: float,
    grid: OccupancyGrid | None,
    radius: float,
) -> str:
    label, pose = docks[i]
    x, y = pose.x, pose.y
    near, d = roads.nearest_node(x, y)
    if near is not None and d < clearance:
        return near
    # a dock on this very spot already (the array test only narrows down the candidates,
    # with a margin; the exact test is the same as before)
    close = np.flatnonzero(np.hypot(xy[:, 0] - x, xy[:, 1] - y) < clearance + 1e-6)
    for j in close.tolist():
        other = docks[j]
        if j != i and other[0] in node_of and math.hypot(xy[j, 0] - x, xy[j, 1] - y) < clearance:
            return node_of[other[0]]
    name = f"dock:{label}"
    dist, edge, t = roads.nearest(x, y)
    candidates: list[tuple[float, float, str | None]] = []  # (x, y, node or None = split)
    if edge is not None and math.isfinite(dist):
        a, b = edge
        (ax, ay), (bx, by) = g.nodes[a]["pos"], g.nodes[b]["pos"]
        seg = math.hypot(bx - ax, by - ay)
        if t * seg < clearance:
            candidates.append((ax, ay, a))
        elif (1.0 - t) * seg < clearance:
            candidates.append((bx, by, b))
        else:
            candidates.append((ax + t * (bx - ax), ay + t * (by - ay), None))
    for n in roads.nearest_nodes(x, y, FALLBACK_NODES):
        px, py = g.nodes[n]["pos"]
        candidates.append((px, py, n))
    for cx, cy, node in candidates:
        if math.hypot(cx - x, cy - y) < clearance:
            continue
        blocker = _first_dock_on(xy, i, (x, y), (cx, cy), clearance)
        if blocker is not None:
            front = docks[blocker][0]
            if front in node_of:  # behind another dock: go through it
                ox, oy = xy[blocker]
                if _free(grid, (x, y), (ox, oy), radius):
                    return _spur(g, name, (x, y), node_of[front])
            continue
        if not _free(grid, (x, y), (cx, cy), radius):
            continue
        if node is None:
            assert edge is not None
            node = _split(g, roads, edge[0], edge[1], t, cx, cy)
        return _spur(g, name, (x, y), node)
    raise DockError(
        f"dock {label!r} at ({x:.2f}, {y:.2f}) cannot be joined to the roadmap: every nearby "
        "connection passes through an obstacle or another dock"
    )


def _first_dock_on(
    xy: np.ndarray, i: int, p: tuple[float, float], q: tuple[float, float], clearance: float
) -> int | None:
    """The dock (other than ``i``) nearest ``p`` among those closer than ``clearance`` to the
    segment ``p``-``q``, or ``None``."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    ll = dx * dx + dy * dy
    if ll <= 0:
        return None
    t = np.clip(((xy[:, 0] - p[0]) * dx + (xy[:, 1] - p[1]) * dy) / ll, 0.0, 1.0)
    d = np.hypot(p[0] + t * dx - xy[:, 0], p[1] + t * dy - xy[:, 1])
    d[np.hypot(xy[:, 0] - p[0], xy[:, 1] - p[1]) < clearance] = np.inf  # this dock (and copies of it)
    d[i] = np.inf
    hits = np.flatnonzero(d < clearance)
    if not len(hits):
        return None
    return int(hits[np.argmin(t[hits])])


def _spur(g: nx.Graph[str], name: str, xy: tuple[float, float], to: str) -> str:
    g.add_node(name, pos=(float(xy[0]), float(xy[1])), dock=True)
    g.add_edge(name, to, length=math.dist(xy, g.nodes[to]["pos"]), spur=True)
    return name


def _split(g: nx.Graph[str], index: _EdgeIndex, a: str, b: str, t: float, fx: float, fy: float) -> str:
    via = f"via:{fx:.2f},{fy:.2f}"
    data = dict(g.edges[a, b])
    length = float(data.pop("length", math.dist(g.nodes[a]["pos"], g.nodes[b]["pos"])))
    g.remove_edge(a, b)
    index.remove_edge(a, b)
    g.add_node(via, pos=(float(fx), float(fy)))
    index.add_node(via, (fx, fy))
    for end, share in ((a, t), (b, 1.0 - t)):
        g.add_edge(end, via, **data, length=length * share)
        index.add_edge(end, via, g.nodes[end]["pos"], (fx, fy))
    return via


def _room(a: np.ndarray, n: int) -> np.ndarray:
    """``a`` with room for a row at index ``n`` (twice the rows when full)."""
    if n < len(a):
        return a
    out = np.full((max(8, 2 * len(a)), a.shape[1]), np.nan)
    out[: len(a)] = a
    return out


def _free(grid: OccupancyGrid | None, p: tuple[float, float], q: tuple[float, float], radius: float) -> bool:
    if grid is None:
        return True
    n = max(1, math.ceil(math.dist(p, q) / grid.resolution))
    if radius > 0:  # every sample in one array pass: the same answers as is_free one by one
        k = np.arange(n + 1)
        return bool(grid.free_at(p[0] + (q[0] - p[0]) * k / n, p[1] + (q[1] - p[1]) * k / n, radius).all())
    return all(
        grid.is_free(p[0] + (q[0] - p[0]) * k / n, p[1] + (q[1] - p[1]) * k / n, radius) for k in range(n + 1)
    )


class _EdgeIndex:
    """Node positions and edge segments as growable NumPy arrays, for nearest queries (the
    arrays grow by doubling, so joining thousands of docks does not copy them per dock)."""

    def __init__(self, g: nx.Graph[str]) -> None:
        self.names: list[str] = [str(n) for n in g.nodes]
        self._xy = np.array([g.nodes[n]["pos"] for n in g.nodes], dtype=float).reshape(-1, 2)
        self.edges: list[tuple[str, str] | None] = [(str(a), str(b)) for a, b in g.edges]
        self._seg = np.array(
            [(*g.nodes[a]["pos"], *g.nodes[b]["pos"]) for a, b in g.edges], dtype=float
        ).reshape(-1, 4)
        self.slot = {frozenset(e): i for i, e in enumerate(self.edges) if e is not None}

    @property
    def xy(self) -> np.ndarray:
        """Node positions, one row per name."""
        return self._xy[: len(self.names)]

    @property
    def seg(self) -> np.ndarray:
        """Edge segments ``(ax, ay, bx, by)``, one row per edge (NaN: removed)."""
        return self._seg[: len(self.edges)]

    def add_node(self, name: str, xy: tuple[float, float]) -> None:
        self._xy = _room(self._xy, len(self.names))
        self._xy[len(self.names)] = xy
        self.names.append(name)

    def add_edge(self, a: str, b: str, pa: tuple[float, float], pb: tuple[float, float]) -> None:
        self.slot[frozenset((a, b))] = len(self.edges)
        self._seg = _room(self._seg, len(self.edges))
        self._seg[len(self.edges)] = (*pa, *pb)
        self.edges.append((a, b))

    def remove_edge(self, a: str, b: str) -> None:
        i = self.slot.pop(frozenset((a, b)))
        self.edges[i] = None
        self.seg[i] = np.nan

    def nearest_node(self, x: float, y: float) -> tuple[str | None, float]:
        if not len(self.xy):
            return None, math.inf
        d = np.hypot(self.xy[:, 0] - x, self.xy[:, 1] - y)
        k = int(np.argmin(d))
        return self.names[k], float(d[k])

    def nearest_nodes(self, x: float, y: float, k: int) -> list[str]:
        """The ``k`` nearest nodes, nearest first, ties to the earlier: the first ``k`` of a
        stable sort, from the few at most as far as the ``k``-th."""
        d = np.hypot(self.xy[:, 0] - x, self.xy[:, 1] - y)
        if len(d) > k:
            few = np.flatnonzero(d <= np.partition(d, k - 1)[k - 1])
            return [self.names[i] for i in few[np.argsort(d[few], kind="stable")][:k]]
        return [self.names[i] for i in np.argsort(d, kind="stable")[:k]]

    def nearest(self, x: float, y: float) -> tuple[float, tuple[str, str] | None, float]:
        """``(distance, edge, t)`` of the edge point nearest ``(x, y)`` (``t`` in [0, 1] from
        the edge's first node); ``(inf, None, 0)`` without edges."""
        if not len(self.seg):
            return math.inf, None, 0.0
        ax, ay, bx, by = self.seg.T
        dx, dy = bx - ax, by - ay
        ll = dx * dx + dy * dy
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.clip(np.where(ll > 0, ((x - ax) * dx + (y - ay) * dy) / ll, 0.0), 0.0, 1.0)
        d = np.hypot(ax + t * dx - x, ay + t * dy - y)
        d = np.where(np.isnan(d), np.inf, d)
        k = int(np.argmin(d))
        e = self.edges[k]
        if e is None or not math.isfinite(float(d[k])):
            return math.inf, None, 0.0
        return float(d[k]), e, float(t[k])
