"""Cells: long roadmap edges cut into short ones keep every way and every path length."""

from __future__ import annotations

import math

import networkx as nx
import pytest

from fleet.roadmap.cells import split_cells
from fleet.roadmap.graph import Roadmap


def _graph() -> nx.Graph[str]:
    g: nx.Graph[str] = nx.Graph()
    for n, xy in {"a": (0.0, 0.0), "b": (5.0, 0.0), "c": (5.0, 1.0), "d": (5.0, 4.0)}.items():
        g.add_node(n, pos=xy)
    g.add_edge("a", "b", spur=False)  # 5 m: cut
    g.add_edge("b", "c", length=1.0)  # 1 m: too short to cut
    g.add_edge("c", "d", length=4.5)  # a curved lane (longer than the straight line): kept whole
    return g


def test_long_straight_edges_are_cut_into_equal_pieces_and_paths_keep_their_length() -> None:
    g = _graph()
    cut = split_cells(g, 1.5, 0.9)
    assert g.number_of_nodes() == 4 and g.has_edge("a", "b")  # the original is not modified
    path = nx.shortest_path(cut, "a", "d", weight="length")
    assert path[0] == "a" and path[-3:] == ["b", "c", "d"]
    cells = path[1:-3]
    assert len(cells) == 3 and all(n.startswith("cell:") for n in cells)  # 4 pieces of 1.25 m
    lengths = [cut.edges[u, v]["length"] for u, v in zip(path, path[1:], strict=False)]
    assert lengths[:4] == pytest.approx([1.25] * 4)
    assert sum(lengths) == pytest.approx(5.0 + 1.0 + 4.5)
    assert all(cut.edges[u, v].get("spur") is False for u, v in zip(path[:4], path[1:5], strict=True))
    for n in cells:  # on the edge, and every piece at least the clearance
        x, y = cut.nodes[n]["pos"]
        assert y == 0.0 and 0 < x < 5
    assert min(lengths) >= 0.9
    Roadmap.from_graph(cut)  # a valid roadmap


def test_pieces_are_never_shorter_than_the_clearance() -> None:
    g = _graph()
    cut = split_cells(g, 0.5, 0.9)  # 10 pieces of 0.5 m would be too short: 5 of 1 m
    path = nx.shortest_path(cut, "a", "b")
    assert len(path) == 6
    assert all(math.isclose(cut.edges[u, v]["length"], 1.0) for u, v in zip(path, path[1:], strict=False))
    with pytest.raises(ValueError, match="cell_m"):
        split_cells(g, 0.0, 0.9)
