"""Compiled distance rows and the bucketed nearest node give what networkx and the whole-array
``argmin`` give, float for float and node for node."""

from __future__ import annotations

import networkx as nx
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.roadmap.distances import Distances
from fleet.roadmap.graph import GRID_FROM_NODES, Roadmap
from fleet.warehouse import plan_layout, roadmap_of


def _networkx_row(rm: Roadmap, d: Distances, source: str) -> np.ndarray:
    ref = np.full(len(d.names), np.inf)
    for n, v in nx.single_source_dijkstra_path_length(rm.graph, source, weight="length").items():
        ref[d.index[str(n)]] = v
    return ref


def _floor() -> Roadmap:
    lay = plan_layout(300, aisles=40, shelf_len=30.0)
    nodes, edges = roadmap_of(lay)
    return Roadmap.from_config_dict({"nodes": nodes, "edges": edges})


def test_rows_equal_networkx_on_a_generated_floor() -> None:
    rm = _floor()
    d = Distances(rm)
    for source in rm.nodes[:: max(1, len(rm) // 60)]:
        assert np.array_equal(d.row(source), _networkx_row(rm, d, source))


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 40),
    edges=st.lists(
        st.tuples(st.integers(0, 39), st.integers(0, 39), st.floats(0.0, 50.0, allow_nan=False)), max_size=120
    ),
)
def test_rows_equal_networkx_on_random_graphs(n: int, edges: list[tuple[int, int, float]]) -> None:
    """Several components (``inf``), zero lengths, self-loops, sums that round differently by
    path: the same floats."""
    g: nx.Graph[str] = nx.Graph()
    for i in range(n):
        g.add_node(f"v{i}", pos=(float(i), 0.0))
    for a, b, w in edges:
        if a < n and b < n:
            g.add_edge(f"v{a}", f"v{b}", length=w * 0.1 + 0.7)
    rm = Roadmap.from_graph(g)
    d = Distances(rm)
    for source in rm.nodes:
        assert np.array_equal(d.row(source), _networkx_row(rm, d, source))


def test_nearest_node_from_buckets_equals_the_whole_array() -> None:
    """Points on nodes, near them, between aisles, exactly between two nodes, and off the map."""
    rm = _floor()
    assert len(rm) >= GRID_FROM_NODES
    xy = np.array([rm.pos(n) for n in rm.nodes])
    rng = np.random.default_rng(5)
    (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
    pts = np.concatenate(
        [
            xy,
            xy + rng.normal(0, 0.7, xy.shape),
            rng.uniform([x0 - 30, y0 - 30], [x1 + 30, y1 + 30], (500, 2)),
            (xy[:-1] + xy[1:]) / 2,
        ]
    )
    for x, y in pts:
        d2 = (xy[:, 0] - x) ** 2 + (xy[:, 1] - y) ** 2
        assert rm.nearest_node(float(x), float(y)) == rm.nodes[int(np.argmin(d2))]
