"""The roadmap as the traffic manager reads it: node positions, adjacency, degrees and edge
lengths in flat dictionaries, the nearest node to a point and an A* shortest path that can
avoid nodes. Read-only once built. Units: meters, ``map`` frame."""

from __future__ import annotations

import heapq
import math
from collections import OrderedDict
from collections.abc import Container, Iterable, Iterator, Mapping, Sequence

import networkx as nx
import numpy as np
import numpy.typing as npt

from fleet.errors import TrafficError
from fleet.roadmap.dijkstra import Csr, FloatArray
from fleet.roadmap.graph import GRID_FROM_NODES, NodeGrid
from fleet.traffic.reservations import edge_key

#: :meth:`RoadIndex.costs_from` keeps its latest rows up to about this many bytes (8 per node
#: and row): 64 MB is 160 rows of a 10,000-robot floor's 50,000 nodes.
COST_ROWS_BYTES = 64 * 2**20

#: :meth:`RoadIndex.shortest` runs compiled (:mod:`fleet.traffic.road_kernels`) when its ends
#: are farther apart than this (m) in a straight line, or its target's heuristic is kept.
LONG_SEARCH_M = 30.0

#: Heuristic arrays (one float per node) kept for the compiled A*'s latest targets.
HEURISTICS_KEPT = 64

#: Target masks kept for :meth:`RoadIndex.costs_near` (one per distinct list of docks asked about).
MASKS_KEPT = 16


class CostRow(Mapping[str, float]):
    """Costs (m) from one node to every node it reaches, read like a ``dict`` (a node it
    does not reach is missing: ``get`` gives the default, ``[]`` raises ``KeyError``); one
    float array over the roadmap's nodes instead of a dict of them. Read-only."""

    __slots__ = ("_index", "_names", "_row")

    def __init__(self, index: dict[str, int], names: list[str], row: FloatArray) -> None:
        self._index, self._names, self._row = index, names, row

    def get(self, key: str, default: float | None = None) -> float | None:  # type: ignore[override]
        i = self._index.get(key)
        if i is None:
            return default
        v: float = self._row.item(i)
        return default if v == math.inf else v

    def __getitem__(self, key: str) -> float:
        v = self.get(key)
        if v is None:
            raise KeyError(key)
        return v

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and self.get(key) is not None

    def __iter__(self) -> Iterator[str]:
        names = self._names
        return (names[i] for i in np.flatnonzero(np.isfinite(self._row)).tolist())

    def __len__(self) -> int:
        return int(np.count_nonzero(np.isfinite(self._row)))


class RoadIndex:
    """Flat lookups over a roadmap graph (node attribute ``pos``, optional edge attribute
    ``length``, else the straight-line distance).

    ``pos[node]``: ``(x, y)``; ``adj[node]``: neighbour nodes; ``deg[node]``: their number;
    ``length[edge_key(a, b)]``: the edge's length (m). Node names are strings.
    ``against[(a, b)]``: extra cost factor of driving edge ``a -> b`` against the fleet's
    flow (see :meth:`set_flow`; empty: no direction is preferred).
    """

    def __init__(self, graph: nx.Graph[str]) -> None:
        self.graph = graph
        self.pos: dict[str, tuple[float, float]] = {
            str(n): (float(d["pos"][0]), float(d["pos"][1])) for n, d in graph.nodes(data=True)
        }
        self._names = list(self.pos)
        self._xy = np.array([self.pos[n] for n in self._names], dtype=float).reshape(-1, 2)
        self.adj: dict[str, list[str]] = {str(n): [str(m) for m in graph.neighbors(n)] for n in graph.nodes}
        self.deg: dict[str, int] = {n: len(a) for n, a in self.adj.items()}
        self.length: dict[tuple[str, str], float] = {}
        for a, b, d in graph.edges(data=True):
            pa, pb = self.pos[str(a)], self.pos[str(b)]
            self.length[edge_key(str(a), str(b))] = float(d.get("length", math.dist(pa, pb)))
        self.against: dict[tuple[str, str], float] = {}
        # compiled searches number the nodes in name order (road_kernels: heap ties)
        self._sorted = sorted(self.pos)
        self._index = {n: i for i, n in enumerate(self._sorted)}
        self._csr: Csr | None = None  # the directed, flow-weighted rows (built when first asked)
        self._rows: OrderedDict[str, CostRow] = OrderedDict()
        self._heur: OrderedDict[str, FloatArray] = OrderedDict()
        self._grid: NodeGrid | None = None  # nearest-node buckets, built on the first query
        self._masks: dict[tuple[str, ...], tuple[npt.NDArray[np.bool_], int]] = {}
        self._xs: list[float] | None = None
        self._ys: list[float] = []

    def set_flow(self, moves: Iterable[tuple[str, str]], penalty: float) -> None:
        """Prefer the fleet's driving direction: ``moves`` are the directed edges robots
        drive (e.g. every step of every patrol loop); from now on :meth:`shortest` costs an
        edge driven against them (its reverse is a move, itself is not) ``1 + penalty``
        times its length. Edges driven both ways, or not at all, keep their length.
        ``penalty`` 0 clears the preference."""
        fwd = {(str(a), str(b)) for a, b in moves if edge_key(str(a), str(b)) in self.length}
        self.against = {(b, a): float(penalty) for a, b in fwd if (b, a) not in fwd and penalty > 0}
        self._csr = None
        self._rows.clear()

    def nearest_node(self, x: float, y: float) -> str:
        """The node nearest ``(x, y)``; raises :class:`TrafficError` on an empty roadmap."""
        if not self._names:
            raise TrafficError("the roadmap has no nodes")
        if len(self._names) < GRID_FROM_NODES:
            d = (self._xy[:, 0] - x) ** 2 + (self._xy[:, 1] - y) ** 2
            return self._names[int(np.argmin(d))]
        if self._grid is None:  # buckets: the node the whole-array argmin gives, ties included
            self._grid = NodeGrid(self._xy)
        return self._names[self._grid.nearest(x, y)]

    def costs_from(self, a: str) -> Mapping[str, float]:
        """Cost (m, edges against the flow weighted as in :meth:`shortest`) of the cheapest
        path from ``a`` to every node it reaches (Dijkstra), as a read-only mapping (nodes it
        does not reach are missing). The very floats of :meth:`costs_from_reference`, from a
        compiled Dijkstra over the directed, flow-weighted roadmap; the last
        :data:`COST_ROWS_BYTES` of rows are kept (the roadmap and the flow do not change
        between :meth:`set_flow` calls), so robots asking again from where they stand (a
        queue for chargers, every cycle) cost a lookup."""
        i = self._index.get(a)
        if i is None:
            raise KeyError(a)
        rows = self._rows
        row = rows.get(a)
        if row is not None:
            rows.move_to_end(a)
            return row
        if self._csr is None:
            self._csr = self._directed_csr()
        row = CostRow(self._index, self._sorted, self._csr.row(i))
        rows[a] = row
        while len(rows) * 8 * max(1, len(self._sorted)) > COST_ROWS_BYTES and len(rows) > 1:
            rows.popitem(last=False)
        return row

    def costs_from_reference(self, a: str) -> dict[str, float]:
        """:meth:`costs_from` as a plain Dijkstra in Python (the reference the compiled rows are
        tested against; a few hundred times slower on a large floor)."""
        adj, lens, against = self.adj, self.length, self.against
        dist = {a: 0.0}
        heap = [(0.0, a)]
        done: set[str] = set()
        while heap:
            d, u = heapq.heappop(heap)
            if u in done:
                continue
            done.add(u)
            for v in adj[u]:
                nd = d + lens[edge_key(u, v)] * (1.0 + against.get((u, v), 0.0))
                if nd < dist.get(v, math.inf):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
        return dist

    def _directed(self) -> Csr:
        """The directed, flow-weighted rows (:meth:`_directed_csr`), built when first asked."""
        if self._csr is None:
            self._csr = self._directed_csr()
        return self._csr

    def _mask(self, targets: Iterable[str]) -> tuple[npt.NDArray[np.bool_], int]:
        """``(mask over the numbered nodes, count)`` of the ``targets`` that are nodes; the
        masks of the latest target lists are kept (the charger queue asks about the same
        docks every cycle)."""
        key = tuple(targets)
        hit = self._masks.get(key)
        if hit is not None:
            return hit
        index = self._index
        mask = np.zeros(len(self._sorted), dtype=np.bool_)
        known = {index[t] for t in key if t in index}
        mask[list(known)] = True
        hit = (mask, len(known))
        self._masks[key] = hit
        if len(self._masks) > MASKS_KEPT:
            self._masks.pop(next(iter(self._masks)))
        return hit

    def _directed_csr(self) -> Csr:
        """The roadmap as directed rows: node ``u``'s entry for ``v`` costs the edge's length
        times ``1 + against[(u, v)]`` (the same float :meth:`costs_from_reference` adds)."""
        index, lens, against = self._index, self.length, self.against
        indptr = np.zeros(len(self._sorted) + 1, dtype=np.int64)
        indices: list[int] = []
        weights: list[float] = []
        for i, u in enumerate(self._sorted):
            for v in self.adj[u]:
                if v == u:
                    continue  # a self-loop never shortens a path
                indices.append(index[v])
                weights.append(lens[edge_key(u, v)] * (1.0 + against.get((u, v), 0.0)))
            indptr[i + 1] = len(indices)
        return Csr(indptr, np.array(indices, dtype=np.int64), np.array(weights, dtype=np.float64))

    def costs_near(self, a: str, targets: Iterable[str], reach: float = math.inf) -> dict[str, float]:
        """:meth:`costs_from` ``a`` of the ``targets`` within ``reach`` (m) of the nearest one:
        ``{t: c for t, c in costs_from(a).items() if t in targets and c <= c0 + reach}``
        where ``c0`` is the least cost of a target (every reachable target when ``reach`` is
        infinite; ``{}`` when none is reachable). The search stops once it is past
        ``c0 + reach`` or has found every target, instead of costing the whole roadmap.
        Compiled (:func:`fleet.traffic.road_kernels.dijkstra_near`): the very floats of
        :meth:`costs_near_reference`."""
        from fleet.traffic.road_kernels import dijkstra_near

        mask, n_want = self._mask(targets)
        if n_want == 0:
            return {}
        i = self._index.get(a)
        if i is None:
            raise KeyError(a)
        csr = self._directed()
        nodes, costs = dijkstra_near(csr.indptr, csr.indices, csr.lengths, i, mask, n_want, float(reach))
        names = self._sorted
        return dict(zip([names[k] for k in nodes.tolist()], costs.tolist(), strict=True))

    def costs_near_reference(
        self, a: str, targets: Iterable[str], reach: float = math.inf
    ) -> dict[str, float]:
        """:meth:`costs_near` as a Dijkstra in Python (the reference the compiled search is
        tested against)."""
        want = set(targets)
        out: dict[str, float] = {}
        if not want:
            return out
        adj, lens, against = self.adj, self.length, self.against
        dist = {a: 0.0}
        heap = [(0.0, a)]
        done: set[str] = set()
        stop = math.inf
        while heap:
            d, u = heapq.heappop(heap)
            if d > stop:
                break
            if u in done:
                continue
            done.add(u)
            if u in want:
                if not out:
                    stop = d + reach
                out[u] = d
                if len(out) == len(want):
                    break
            for v in adj[u]:
                nd = d + lens[edge_key(u, v)] * (1.0 + against.get((u, v), 0.0))
                if nd < dist.get(v, math.inf):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
        return out

    def cost(self, nodes: Sequence[str], flow: bool = True) -> float:
        """Cost (m, edges against the flow weighted as in :meth:`shortest`; with
        ``flow=False`` the length) of driving the node path ``nodes`` (consecutive nodes are
        edges or repeats)."""
        lens = self.length
        against: dict[tuple[str, str], float] = self.against if flow else {}
        total = 0.0
        for u, v in zip(nodes, nodes[1:], strict=False):
            if u != v:
                total += lens[edge_key(u, v)] * (1.0 + against.get((u, v), 0.0))
        return total

    def nearest(self, a: str, candidates: Iterable[str]) -> str | None:
        """The candidate of least :meth:`costs_from` ``a`` (ties: the least name; one that
        cannot be reached only if none can: then the least name); ``None`` for none. The same
        answer as ``min(candidates, key=lambda c: (costs_from(a).get(c, inf), c))``, but the
        search stops at the nearest candidate instead of costing the whole roadmap. Compiled
        (:func:`fleet.traffic.road_kernels.dijkstra_nearest`): the answer of
        :meth:`nearest_reference`."""
        from fleet.traffic.road_kernels import dijkstra_nearest

        want = set(candidates)
        if not want:
            return None
        i = self._index.get(a)
        if i is None:
            raise KeyError(a)
        index = self._index
        mask = np.zeros(len(self._sorted), dtype=np.bool_)
        known = [index[c] for c in want if c in index]
        mask[known] = True
        csr = self._directed()
        best = dijkstra_nearest(csr.indptr, csr.indices, csr.lengths, i, mask)
        return self._sorted[best] if best >= 0 else min(want)

    def nearest_reference(self, a: str, candidates: Iterable[str]) -> str | None:
        """:meth:`nearest` as a Dijkstra in Python (the reference the compiled search is
        tested against)."""
        want = set(candidates)
        if not want:
            return None
        adj, lens, against = self.adj, self.length, self.against
        dist = {a: 0.0}
        heap = [(0.0, a)]
        done: set[str] = set()
        best: str | None = None
        best_d = math.inf
        while heap:
            d, u = heapq.heappop(heap)
            if d > best_d:
                break
            if u in done:
                continue
            done.add(u)
            if u in want and (best is None or d < best_d or u < best):
                best, best_d = u, d
            for v in adj[u]:
                nd = d + lens[edge_key(u, v)] * (1.0 + against.get((u, v), 0.0))
                if nd < dist.get(v, math.inf):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
        return best if best is not None else min(want)

    def shortest(
        self,
        a: str,
        b: str,
        avoid: Container[str],
        limit: float = math.inf,
        *,
        flow: bool = True,
        avoid_moves: Container[tuple[str, str]] = (),
    ) -> list[str] | None:
        """A* from ``a`` to ``b`` by edge length (straight-line heuristic), not entering nodes
        in ``avoid`` nor driving a step ``(u, v)`` in ``avoid_moves``; ``None`` if there is no
        such path of cost at most ``limit`` (m). An edge driven against the flow
        (:meth:`set_flow`) costs ``1 + penalty`` times its length (with ``flow=False``, its
        length)."""
        if a == b:
            return [a]
        if b in avoid:
            return None
        if flow and _empty(avoid) and _empty(avoid_moves) and self._worth_compiling(a, b):
            return self._shortest_compiled(a, b, limit)
        return self.shortest_reference(a, b, avoid, limit, flow=flow, avoid_moves=avoid_moves)

    def shortest_reference(
        self,
        a: str,
        b: str,
        avoid: Container[str],
        limit: float = math.inf,
        *,
        flow: bool = True,
        avoid_moves: Container[tuple[str, str]] = (),
    ) -> list[str] | None:
        """:meth:`shortest` as the A* in Python (used for searches that avoid nodes or steps,
        and for short ones; the compiled search is tested against it)."""
        if a == b:
            return [a]
        if b in avoid:
            return None
        pos = self.pos
        bx, by = pos[b]
        dist = {a: 0.0}
        prev: dict[str, str] = {}
        heap = [(math.dist(pos[a], (bx, by)), 0.0, a)]
        adj, lens = self.adj, self.length
        against: dict[tuple[str, str], float] = self.against if flow else {}
        closed: set[str] = set()
        while heap:
            f, d, u = heapq.heappop(heap)
            if f > limit:
                return None
            if u == b:
                out = [b]
                while out[-1] != a:
                    out.append(prev[out[-1]])
                return out[::-1]
            if u in closed:
                continue
            closed.add(u)
            for v in adj[u]:
                if v in avoid or v in closed or (u, v) in avoid_moves:
                    continue
                nd = d + lens[edge_key(u, v)] * (1.0 + against.get((u, v), 0.0))
                if nd < dist.get(v, math.inf):
                    dist[v] = nd
                    prev[v] = u
                    vx, vy = pos[v]
                    heapq.heappush(heap, (nd + math.hypot(vx - bx, vy - by), nd, v))
        return None

    def _worth_compiling(self, a: str, b: str) -> bool:
        """Whether the compiled A* pays for its heuristic array (one ``math.hypot`` per node,
        kept per target): when the array is kept already, or the search may be long."""
        if b in self._heur:
            return True
        ax, ay = self.pos[a]
        bx, by = self.pos[b]
        return (ax - bx) * (ax - bx) + (ay - by) * (ay - by) > LONG_SEARCH_M * LONG_SEARCH_M

    def _sorted_xy(self) -> tuple[list[float], list[float]]:
        """The nodes' x and y (m) in name order (kept)."""
        if self._xs is None:
            self._xs = [self.pos[n][0] for n in self._sorted]
            self._ys = [self.pos[n][1] for n in self._sorted]
        return self._xs, self._ys

    def _shortest_compiled(self, a: str, b: str, limit: float) -> list[str] | None:
        """:meth:`shortest` with the flow and nothing to avoid, compiled (road_kernels)."""
        from fleet.traffic.road_kernels import astar

        if self._csr is None:
            self._csr = self._directed_csr()
        heur = self._heur.get(b)
        bx, by = self.pos[b]
        if heur is None:
            xs, ys = self._sorted_xy()
            heur = np.array(
                list(map(math.hypot, [x - bx for x in xs], [y - by for y in ys])), dtype=np.float64
            )
            self._heur[b] = heur
            if len(self._heur) > HEURISTICS_KEPT:
                self._heur.popitem(last=False)
        else:
            self._heur.move_to_end(b)
        csr, index = self._csr, self._index
        f0 = math.dist(self.pos[a], (bx, by))
        out = astar(csr.indptr, csr.indices, csr.lengths, heur, index[a], index[b], f0, limit)
        if out.size == 0:
            return None
        names = self._sorted
        return [names[i] for i in out.tolist()]


def _empty(c: Container[object]) -> bool:
    """Whether ``c`` is a plain collection with nothing in it (an avoid set of a search)."""
    return isinstance(c, (set, frozenset, tuple, list, dict)) and not c
