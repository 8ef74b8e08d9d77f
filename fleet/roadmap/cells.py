"""Cells: long roadmap edges cut into short ones, so robots driving the same way can follow
each other closely under traffic management.

The traffic manager (:mod:`fleet.traffic`) reserves whole nodes and edges: a robot following
another one along an aisle whose nodes stand one shelf bay (about 5 m) apart stays a whole
bay behind it, and stops at every node. :func:`split_cells` returns a copy of the roadmap in
which every straight edge longer than ``cell_m`` is cut into equal pieces of at most
``cell_m`` by new nodes (``cell:<x>,<y>``, on the edge, its ``length`` shared in proportion):
the same ways and the same path lengths, finer reservations. A piece is never shorter than
``clearance`` (the manager's minimum edge length); an edge whose ``length`` differs from the
straight line between its ends (a curved lane) is left whole. The original graph is not
modified. Units: meters.
"""

from __future__ import annotations

import math

import networkx as nx

#: An edge counts as straight when its ``length`` is within this fraction of the distance
#: between its ends.
STRAIGHT_TOL = 0.01


def split_cells(graph: nx.Graph[str], cell_m: float, clearance: float) -> nx.Graph[str]:
    """A copy of ``graph`` with every straight edge longer than ``cell_m`` cut into
    ``ceil(length / cell_m)`` equal pieces (fewer when a piece would be shorter than
    ``clearance``). Edge attributes other than ``length`` are copied to every piece. Raises
    ``ValueError`` unless ``cell_m > 0``."""
    if not cell_m > 0:
        raise ValueError(f"cell_m must be positive, got {cell_m}")
    g = graph.copy()
    for a, b, data in list(graph.edges(data=True)):
        pa, pb = graph.nodes[a]["pos"], graph.nodes[b]["pos"]
        straight = math.dist(pa, pb)
        length = float(data.get("length", straight))
        if straight <= 0 or abs(length - straight) > STRAIGHT_TOL * straight:
            continue
        n = min(math.ceil(length / cell_m - 1e-9), math.floor(length / clearance + 1e-9))
        if n < 2:
            continue
        rest = {k: v for k, v in data.items() if k != "length"}
        g.remove_edge(a, b)
        prev = a
        for k in range(1, n):
            t = k / n
            x, y = pa[0] + (pb[0] - pa[0]) * t, pa[1] + (pb[1] - pa[1]) * t
            name = f"cell:{x:.2f},{y:.2f}"
            if name in g:  # two edges crossing at the same point: keep their cells apart
                name = f"cell:{x:.2f},{y:.2f}:{a}-{b}"
            g.add_node(name, pos=(float(x), float(y)), cell=True)
            g.add_edge(prev, name, **rest, length=length / n)
            prev = name
        g.add_edge(prev, b, **rest, length=length / n)
    return g
