"""Roadmap -> SUMO network (plain XML, netconvert, cache) and .net.xml -> roadmap graph."""

from __future__ import annotations

import math
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import networkx as nx
import pytest

from fleet.errors import ConfigError
from fleet.roadmap.netxml import read_network
from sim.sumo.net import (
    NetSettings,
    as_graph,
    build_network,
    grid_roadmap,
    junction_ids,
    settings_for_robot,
    sumo_binary,
    write_plain_xml,
)

pytestmark = pytest.mark.sumo
sumolib = pytest.importorskip("sumolib")
pytest.importorskip("sumo")

SETTINGS = settings_for_robot(0.3, 1.0)


def tee_roadmap() -> nx.Graph:
    """A straight aisle a - b - c - d (10 m apart) with a spur b - s (8 m north of b)."""
    g = nx.Graph()
    for name, pos in {
        "a": (0.0, 0.0),
        "b": (10.0, 0.0),
        "c": (20.0, 0.0),
        "d": (30.0, 0.0),
        "s": (10.0, 8.0),
    }.items():
        g.add_node(name, pos=pos)
    g.add_edges_from([("a", "b"), ("b", "c"), ("c", "d"), ("b", "s")])
    return g


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("sumo-cache")


@pytest.fixture(scope="module")
def tee_net(cache: Path) -> tuple[nx.Graph, object]:
    g = tee_roadmap()
    built = build_network(g, SETTINGS, cache)
    return g, built


def test_plain_xml_has_a_node_per_roadmap_node_and_two_edges_per_roadmap_edge(tmp_path: Path) -> None:
    g = tee_roadmap()
    nod, edg, jid, edge_of = write_plain_xml(g, tmp_path, "t", SETTINGS)
    nodes = {n.get("id"): (float(n.get("x")), float(n.get("y"))) for n in ET.parse(nod).getroot()}
    assert nodes == {n: g.nodes[n]["pos"] for n in g.nodes}
    edges = ET.parse(edg).getroot()
    pairs = {(e.get("from"), e.get("to")) for e in edges}
    assert len(edges) == 2 * g.number_of_edges()
    for u, v in g.edges:
        assert (u, v) in pairs and (v, u) in pairs
        assert edge_of[(u, v)] != edge_of[(v, u)]
    assert all(e.get("numLanes") == "1" and float(e.get("width")) == pytest.approx(0.9) for e in edges)
    assert jid == {n: n for n in g.nodes}


def test_unsafe_node_names_get_generated_junction_ids() -> None:
    g = nx.Graph()
    g.add_node("aisle 1/south", pos=(0.0, 0.0))
    g.add_node(("tuple", 2), pos=(5.0, 0.0))
    assert junction_ids(g) == {"aisle 1/south": "n0", ("tuple", 2): "n1"}


def test_network_has_junctions_at_nodes_and_lanes_both_ways(tee_net: tuple[nx.Graph, object]) -> None:
    g, built = tee_net
    net = sumolib.net.readNet(str(built.net_path), withInternal=True)
    for n in g.nodes:
        x, y = net.getNode(n).getCoord()
        assert (x, y) == pytest.approx(g.nodes[n]["pos"], abs=1e-6)
    for u, v in g.edges:
        fwd, back = net.getEdge(built.edge_of[(u, v)]), net.getEdge(built.edge_of[(v, u)])
        assert (fwd.getFromNode().getID(), fwd.getToNode().getID()) == (u, v)
        assert (back.getFromNode().getID(), back.getToNode().getID()) == (v, u)
        assert fwd.getLaneNumber() == back.getLaneNumber() == 1
        assert fwd.getSpeed() == pytest.approx(1.0)
        # an edge is its roadmap length minus the junction areas at its two ends
        length = math.dist(g.nodes[u]["pos"], g.nodes[v]["pos"])
        assert length - 2 * 2 * SETTINGS.lane_width <= fwd.getLength() <= length


def test_straight_drive_through_junctions_is_as_long_as_the_roadmap(tee_net: tuple[nx.Graph, object]) -> None:
    g, built = tee_net
    net = sumolib.net.readNet(str(built.net_path), withInternal=True)
    path = ["a", "b", "c", "d"]
    edges = [net.getEdge(built.edge_of[(u, v)]) for u, v in zip(path, path[1:], strict=False)]
    total = sum(e.getLength() for e in edges)
    for e1, e2 in zip(edges, edges[1:], strict=False):
        (conn,) = e1.getConnections(e2)
        total += net.getLane(conn.getViaLaneID()).getLength()
    # SUMO gives the zero-length lane through the straight node c a minimum length of 0.1 m
    assert total == pytest.approx(30.0, abs=0.15)


def test_u_turns_exist_at_dead_ends_and_straight_nodes(tee_net: tuple[nx.Graph, object]) -> None:
    g, built = tee_net
    net = sumolib.net.readNet(str(built.net_path))
    for u, v in [("c", "d"), ("b", "c"), ("a", "b")]:  # d: dead end, c: straight-through node
        fwd, back = net.getEdge(built.edge_of[(u, v)]), net.getEdge(built.edge_of[(v, u)])
        assert fwd.getConnections(back), f"no U-turn at {v}"


def test_build_is_cached_by_content(cache: Path, tee_net: tuple[nx.Graph, object]) -> None:
    g, built = tee_net
    again = build_network(tee_roadmap(), SETTINGS, cache)
    assert again.cached and again.net_path == built.net_path
    moved = tee_roadmap()
    moved.nodes["s"]["pos"] = (10.0, 9.0)
    other = build_network(moved, SETTINGS, cache)
    assert not other.cached and other.net_path != built.net_path
    wider = build_network(tee_roadmap(), NetSettings(lane_width=1.2), cache)
    assert wider.net_path not in (built.net_path, other.net_path)


def test_net_xml_round_trips_to_the_same_graph(tee_net: tuple[nx.Graph, object]) -> None:
    from fleet.roadmap.graph import Roadmap

    g, built = tee_net
    back = read_network(built.net_path)
    assert set(back.nodes) == set(g.nodes)
    assert {frozenset(e) for e in back.edges} == {frozenset(e) for e in g.edges}
    for n in g.nodes:
        assert back.nodes[n]["pos"] == pytest.approx(g.nodes[n]["pos"])
    for u, v in g.edges:
        assert back.edges[u, v]["length"] == pytest.approx(math.dist(g.nodes[u]["pos"], g.nodes[v]["pos"]))
    assert back.graph["sumo_net"] == str(Path(built.net_path).resolve())
    rm = Roadmap.from_graph(back)
    assert rm.shortest_path("a", "d") == ["a", "b", "c", "d"]
    assert as_graph(rm) is rm.graph


def test_foreign_net_xml_reads_as_a_connected_roadmap(tmp_path: Path) -> None:
    """A network SUMO made itself (as netedit would) with curved-free grid streets."""
    net = tmp_path / "grid.net.xml"
    subprocess.run(
        [
            str(sumo_binary("netgenerate")),
            "--grid",
            "--grid.number",
            "3",
            "--grid.length",
            "15",
            "--no-internal-links",
            "true",
            "-o",
            str(net),
        ],
        check=True,
        capture_output=True,
    )
    g = read_network(net)
    assert g.number_of_nodes() == 9 and g.number_of_edges() == 12
    assert nx.is_connected(g)
    assert all(d["length"] == pytest.approx(15.0) for _, _, d in g.edges(data=True))


def test_read_network_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        read_network(tmp_path / "missing.net.xml")
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<routes/>")
    with pytest.raises(ConfigError, match="bad.net.xml"):
        read_network(bad)


def test_bad_roadmaps_raise_config_errors(tmp_path: Path) -> None:
    g = nx.Graph()
    g.add_node("a", pos=(0.0, 0.0))
    g.add_node("b")
    g.add_edge("a", "b")
    with pytest.raises(ConfigError, match=r"roadmap.nodes.b"):
        build_network(g, SETTINGS, tmp_path)
    g2 = nx.Graph()
    g2.add_node("a", pos=(0.0, 0.0))
    g2.add_node("b", pos=(0.0, 0.0))
    g2.add_edge("a", "b")
    with pytest.raises(ConfigError, match="same position"):
        build_network(g2, SETTINGS, tmp_path)


def test_grid_roadmap_shape() -> None:
    g = grid_roadmap(4, 3, 5.0)
    assert g.number_of_nodes() == 12 and g.number_of_edges() == 4 * 2 + 3 * 3
    assert g.nodes["g3_2"]["pos"] == (15.0, 10.0)
