"""The roadmap as the traffic manager reads it: node positions, adjacency, degrees and edge
lengths in flat dictionaries, the nearest node to a point and an A* shortest path that can
avoid nodes. Read-only once built. Units: meters, ``map`` frame."""

from __future__ import annotations

import heapq
import math
from collections.abc import Container, Iterable, Sequence

import networkx as nx
import numpy as np

from fleet.errors import TrafficError
from fleet.traffic.reservations import edge_key


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

    def set_flow(self, moves: Iterable[tuple[str, str]], penalty: float) -> None:
        """Prefer the fleet's driving direction: ``moves`` are the directed edges robots
        drive (e.g. every step of every patrol loop); from now on :meth:`shortest` costs an
        edge driven against them (its reverse is a move, itself is not) ``1 + penalty``
        times its length. Edges driven both ways, or not at all, keep their length.
        ``penalty`` 0 clears the preference."""
        fwd = {(str(a), str(b)) for a, b in moves if edge_key(str(a), str(b)) in self.length}
        self.against = {(b, a): float(penalty) for a, b in fwd if (b, a) not in fwd and penalty > 0}

    def nearest_node(self, x: float, y: float) -> str:
        """The node nearest ``(x, y)``; raises :class:`TrafficError` on an empty roadmap."""
        if not self._names:
            raise TrafficError("the roadmap has no nodes")
        d = (self._xy[:, 0] - x) ** 2 + (self._xy[:, 1] - y) ** 2
        return self._names[int(np.argmin(d))]

    def costs_from(self, a: str) -> dict[str, float]:
        """Cost (m, edges against the flow weighted as in :meth:`shortest`) of the cheapest
        path from ``a`` to every node it reaches (Dijkstra)."""
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

    def costs_near(self, a: str, targets: Iterable[str], reach: float = math.inf) -> dict[str, float]:
        """:meth:`costs_from` ``a`` of the ``targets`` within ``reach`` (m) of the nearest one:
        ``{t: c for t, c in costs_from(a).items() if t in targets and c <= c0 + reach}``
        where ``c0`` is the least cost of a target (every reachable target when ``reach`` is
        infinite; ``{}`` when none is reachable). The search stops once it is past
        ``c0 + reach`` or has found every target, instead of costing the whole roadmap."""
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
        search stops at the nearest candidate instead of costing the whole roadmap."""
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
