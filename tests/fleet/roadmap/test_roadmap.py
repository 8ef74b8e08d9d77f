"""Roadmap queries: shortest paths, nearest node, travel cost, dense route loops, poses."""

from __future__ import annotations

import math

import networkx as nx
import pytest

from fleet.errors import ConfigError
from fleet.roadmap.graph import Roadmap
from fleet.types import Pose2D


@pytest.fixture
def ladder() -> Roadmap:
    """Two 10 m aisles (x = 0 and x = 4) joined at both ends, plus a dead-end spur."""
    return Roadmap.from_config_dict(
        {
            "nodes": {
                "a1_s": [0.0, 0.0],
                "a1_m": [0.0, 5.0],
                "a1_n": [0.0, 10.0],
                "a2_s": [4.0, 0.0],
                "a2_m": [4.0, 5.0],
                "a2_n": [4.0, 10.0],
                "spur": [8.0, 0.0],
            },
            "edges": [
                ["a1_s", "a1_m"],
                ["a1_m", "a1_n"],
                ["a2_s", "a2_m"],
                ["a2_m", "a2_n"],
                ["a1_s", "a2_s"],
                ["a1_n", "a2_n"],
                ["a2_s", "spur"],
            ],
        }
    )


def test_edges_get_straight_line_lengths(ladder: Roadmap) -> None:
    assert ladder.edge_length("a1_s", "a2_s") == pytest.approx(4.0)
    assert ladder.edge_length("a1_m", "a1_n") == pytest.approx(5.0)
    assert ladder.pos("a2_m") == (4.0, 5.0)
    assert ladder.nodes[0] == "a1_s" and len(ladder) == 7


def test_shortest_path_takes_the_short_way_round(ladder: Roadmap) -> None:
    assert ladder.shortest_path("a1_m", "a2_s") == ["a1_m", "a1_s", "a2_s"]
    assert ladder.shortest_path("a1_n", "spur") == ["a1_n", "a2_n", "a2_m", "a2_s", "spur"]
    assert ladder.distance("a1_n", "spur") == pytest.approx(4 + 10 + 4)
    assert ladder.shortest_path("a1_s", "a1_s") == ["a1_s"]


def test_unreachable_node_gives_empty_path_and_infinite_cost() -> None:
    g = nx.Graph()
    g.add_node("a", pos=(0, 0))
    g.add_node("b", pos=(5, 0))
    rm = Roadmap.from_graph(g)
    assert rm.shortest_path("a", "b") == []
    assert rm.travel_cost(Pose2D(0, 1), "b") == math.inf
    assert not rm.is_connected()
    with pytest.raises(KeyError):
        rm.shortest_path("a", "nope")
    assert rm.shortest_path("a", "b") == []  # remembered: still empty, still no error


def test_remembered_paths_are_the_same_and_not_shared(ladder: Roadmap) -> None:
    """Shortest paths are remembered (route copies ask for the same legs): asking again gives
    an equal path, and changing a returned list does not change the next answer."""
    first = ladder.shortest_path("a1_n", "spur")
    first.append("junk")
    assert ladder.shortest_path("a1_n", "spur") == ["a1_n", "a2_n", "a2_m", "a2_s", "spur"]
    with pytest.raises(KeyError):
        ladder.shortest_path("nope", "spur")


def test_nearest_node_and_travel_cost(ladder: Roadmap) -> None:
    assert ladder.nearest_node(3.5, 6.0) == "a2_m"
    assert ladder.nearest_node(-1.0, -1.0) == "a1_s"
    # 1 m to a1_s, then 4 m along the south corridor and 5 m up aisle 2.
    assert ladder.travel_cost(Pose2D(0.0, -1.0, 0.0), "a2_m") == pytest.approx(1 + 4 + 5)


def test_expand_route_is_a_closed_loop_of_adjacent_nodes(ladder: Roadmap) -> None:
    loop = ladder.expand_route(["a1_s", "a1_n", "a2_n", "a2_s"])
    assert loop == ["a1_s", "a1_m", "a1_n", "a2_n", "a2_m", "a2_s"]
    for a, b in zip(loop, loop[1:] + loop[:1], strict=True):
        assert b in ladder.neighbors(a)
    assert ladder.path_length(loop + loop[:1]) == pytest.approx(28.0)


def test_expand_route_closing_leg_through_other_nodes(ladder: Roadmap) -> None:
    loop = ladder.expand_route(["a1_n", "spur"])
    assert loop[0] == "a1_n" and "spur" in loop
    assert loop[-1] in ladder.neighbors("a1_n")
    open_path = ladder.expand_route(["a1_n", "spur"], closed=False)
    assert open_path == ["a1_n", "a2_n", "a2_m", "a2_s", "spur"]


def test_poses_face_the_direction_of_travel(ladder: Roadmap) -> None:
    poses = ladder.poses_for(["a1_s", "a1_m", "a1_n", "a2_n"])
    assert [p.theta for p in poses] == pytest.approx([math.pi / 2, math.pi / 2, 0.0, 0.0])
    closed = ladder.poses_for(["a1_s", "a1_n", "a2_n", "a2_s"], closed=True)
    assert closed[-1].theta == pytest.approx(math.pi)  # back west to the start
    assert (closed[1].x, closed[1].y) == (0.0, 10.0)


def test_config_dict_round_trip_and_networkx_copy(ladder: Roadmap) -> None:
    again = Roadmap.from_config_dict(ladder.to_config_dict())
    assert again.nodes == ladder.nodes and again.edges == ladder.edges
    g = ladder.to_networkx()
    g.remove_node("spur")
    assert "spur" in ladder


def test_from_graph_keeps_given_lengths() -> None:
    g = nx.Graph()
    g.add_node(1, pos=(0.0, 0.0))
    g.add_node(2, pos=(3.0, 4.0))
    g.add_edge(1, 2, length=7.5)  # e.g. a curved lane
    g.add_node(3, pos=(3.0, 0.0))
    g.add_edge(1, 3)
    rm = Roadmap.from_graph(g)
    assert rm.edge_length("1", "2") == 7.5
    assert rm.edge_length("1", "3") == 3.0


@pytest.mark.parametrize(
    ("section", "field", "word"),
    [
        ({"nodes": {"a": [0, 0]}, "edges": [["a", "zz"]]}, "roadmap.edges[0]", "unknown roadmap node"),
        ({"nodes": {"a": [0, 0, 0]}}, "roadmap.nodes.a", "[x, y]"),
        ({"nodes": {}}, "roadmap.nodes", "non-empty"),
        ({"nodes": {"a": [0, 0]}, "edges": [["a", "a"]]}, "roadmap.edges[0]", "itself"),
        (
            {"nodes": {"a": [0, 0], "b": [1, 0]}, "edges": [["a", "b"], ["b", "a"]]},
            "roadmap.edges[1]",
            "duplicate",
        ),
        ({"nodes": {"a": [0, 0]}, "lanes": []}, "roadmap.lanes", "unknown key"),
    ],
)
def test_bad_roadmap_sections(section: dict, field: str, word: str) -> None:
    with pytest.raises(ConfigError) as ei:
        Roadmap.from_config_dict(section, "f.yaml")
    assert str(ei.value).startswith(f"f.yaml: {field}: ")
    assert word in str(ei.value)
