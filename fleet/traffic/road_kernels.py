"""Compiled searches over the traffic manager's roadmap (:class:`fleet.traffic.roads.RoadIndex`):
the A* of :meth:`~fleet.traffic.roads.RoadIndex.shortest` for paths that avoid nothing, and the
bounded Dijkstras of :meth:`~fleet.traffic.roads.RoadIndex.costs_near` and
:meth:`~fleet.traffic.roads.RoadIndex.nearest` (the charger queue's searches, every cycle).

It must return the very path the Python A* returns, ties included, so that no decision of the
traffic manager changes. It does so by doing the same thing step by step:

* nodes are numbered in the order of their names (``sorted``), so a heap entry
  ``(f, d, node number)`` compares exactly as the Python entry ``(f, d, node name)`` does;
* each node's neighbours are listed in the Python adjacency's order, with the same
  flow-weighted edge costs (the same doubles), and self-loops left out (the Python search
  never takes one: the node is closed when its neighbours are expanded);
* the straight-line heuristic is an array computed in Python with ``math.hypot``, the
  function the Python search calls (a compiled ``hypot`` may round differently);
* numba's ``heapq`` is CPython's ``heapq`` algorithm, so pushes and pops leave the heap in
  the same order.

Units: meters."""

from __future__ import annotations

import heapq

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def astar(
    indptr: np.ndarray,
    indices: np.ndarray,
    weights: np.ndarray,
    heur: np.ndarray,
    a: int,
    b: int,
    f0: float,
    limit: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """Node numbers of the path from ``a`` to ``b`` (both included), or an empty array when
    there is none of cost at most ``limit``. ``heur[v]``: the heuristic of node ``v`` towards
    ``b``; ``f0``: the start entry's estimate (as the Python search computes it)."""
    n = indptr.shape[0] - 1
    dist = np.full(n, np.inf)
    prev = np.full(n, -1, dtype=np.int64)
    closed = np.zeros(n, dtype=np.bool_)
    dist[a] = 0.0
    heap = [(f0, 0.0, a)]
    while heap:
        f, d, u = heapq.heappop(heap)
        if f > limit:
            return np.empty(0, dtype=np.int64)
        if u == b:
            k = 1
            v = b
            while v != a:
                v = prev[v]
                k += 1
            out = np.empty(k, dtype=np.int64)
            v = b
            for i in range(k - 1, -1, -1):
                out[i] = v
                if v != a:
                    v = prev[v]
            return out
        if closed[u]:
            continue
        closed[u] = True
        for k in range(indptr[u], indptr[u + 1]):
            v = indices[k]
            if closed[v]:
                continue
            nd = d + weights[k]
            if nd < dist[v]:
                dist[v] = nd
                prev[v] = u
                heapq.heappush(heap, (nd + heur[v], nd, v))
    return np.empty(0, dtype=np.int64)


@njit(cache=True, nogil=True)
def _relax(
    indptr: np.ndarray,
    indices: np.ndarray,
    weights: np.ndarray,
    u: int,
    d: float,
    dist: np.ndarray,
    heap: list[tuple[float, int]],
) -> None:  # pragma: no cover - compiled
    """The Dijkstras' step from node ``u`` settled at cost ``d``: every neighbour reached
    cheaper than ``dist`` has it lowered and is pushed on ``heap`` (one double addition per
    edge, as in the Python searches)."""
    for k in range(indptr[u], indptr[u + 1]):
        v = indices[k]
        nd = d + weights[k]
        if nd < dist[v]:
            dist[v] = nd
            heapq.heappush(heap, (nd, v))


@njit(cache=True, nogil=True)
def dijkstra_near(
    indptr: np.ndarray,
    indices: np.ndarray,
    weights: np.ndarray,
    a: int,
    want: np.ndarray,
    n_want: int,
    reach: float,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """``(nodes, costs)`` of the wanted nodes (``want[v]``; ``n_want`` of them) settled by a
    Dijkstra from ``a`` until it is past ``reach`` beyond the first one settled, or has
    settled all of them, in the order settled. A node's cost is ``min(dist[u] + weight)``
    over the neighbours settled before it, one double addition per edge, as in the Python
    search: the same floats, whatever order ties leave the heap in."""
    n = indptr.shape[0] - 1
    dist = np.full(n, np.inf)
    done = np.zeros(n, dtype=np.bool_)
    nodes = np.empty(n_want, dtype=np.int64)
    costs = np.empty(n_want, dtype=np.float64)
    found = 0
    stop = np.inf
    dist[a] = 0.0
    heap = [(0.0, a)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > stop:
            break
        if done[u]:
            continue
        done[u] = True
        if want[u]:
            if found == 0:
                stop = d + reach
            nodes[found] = u
            costs[found] = d
            found += 1
            if found == n_want:
                break
        _relax(indptr, indices, weights, u, d, dist, heap)
    return nodes[:found], costs[:found]


@njit(cache=True, nogil=True)
def dijkstra_nearest(
    indptr: np.ndarray, indices: np.ndarray, weights: np.ndarray, a: int, want: np.ndarray
) -> int:  # pragma: no cover - compiled
    """The wanted node (``want[v]``) of least cost from ``a``, ties to the least node number
    (nodes are numbered in name order); -1 when none is reached. The search stops once past
    the best cost found."""
    n = indptr.shape[0] - 1
    dist = np.full(n, np.inf)
    done = np.zeros(n, dtype=np.bool_)
    best = -1
    best_d = np.inf
    dist[a] = 0.0
    heap = [(0.0, a)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > best_d:
            break
        if done[u]:
            continue
        done[u] = True
        if want[u] and (best < 0 or d < best_d or u < best):
            best = u
            best_d = d
        _relax(indptr, indices, weights, u, d, dist, heap)
    return best


__all__ = ["astar", "dijkstra_near", "dijkstra_nearest"]
