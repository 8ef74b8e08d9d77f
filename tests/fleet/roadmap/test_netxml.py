"""A fleet config whose roadmap is a SUMO network (``roadmap: {net: file.net.xml}``).

Round trip (roadmap -> netconvert -> .net.xml -> sumolib -> roadmap), the shipped example
(``configs/warehouse_netxml.yaml``), one clear ``<file>: roadmap.net: <reason>`` error per
kind of bad input, and a short SUMO fleet run on the example's own network.

Real sumolib, netconvert and libsumo; real files in ``tmp_path``.
"""

from __future__ import annotations

import copy
import json
import math
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from fleet.config.loader import load_config
from fleet.errors import ConfigError
from fleet.roadmap.graph import Roadmap

pytestmark = pytest.mark.sumo
pytest.importorskip("sumolib")
pytest.importorskip("sumo")

from sim.sumo.net import build_network, settings_for_robot, write_network  # noqa: E402

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
PATROL = CONFIGS / "warehouse_patrol.yaml"
NETXML = CONFIGS / "warehouse_netxml.yaml"
SHIPPED_NET = CONFIGS / "nets" / "warehouse_small.net.xml"


@pytest.fixture(scope="module")
def patrol_doc() -> dict[str, Any]:
    return dict(yaml.safe_load(PATROL.read_text()))


@pytest.fixture(scope="module")
def netxml_doc() -> dict[str, Any]:
    return dict(yaml.safe_load(NETXML.read_text()))


def edges_of(rm: Roadmap) -> set[frozenset[str]]:
    return {frozenset(e) for e in rm.edges}


def assert_same_roadmap(got: Roadmap, want: Roadmap) -> None:
    """Same node names, positions within 1 cm, same edges with the same lengths (1 cm)."""
    assert set(got.nodes) == set(want.nodes)
    for n in want.nodes:
        assert math.dist(got.pos(n), want.pos(n)) < 0.01, n
    assert edges_of(got) == edges_of(want)
    for a, b in want.edges:
        assert got.edge_length(a, b) == pytest.approx(want.edge_length(a, b), abs=0.01)


def write_config(tmp_path: Path, doc: dict[str, Any], roadmap: Any, name: str = "fleet.yaml") -> Path:
    """``doc`` with ``roadmap`` replaced, saved in ``tmp_path`` (the map path made absolute)."""
    doc = copy.deepcopy(doc)
    doc["map"] = str(CONFIGS / doc["map"])
    doc["roadmap"] = roadmap
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def config_error(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        load_config(path)
    return err.value


# ----------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("internal_links", [False, True])
def test_a_generated_network_reads_back_as_the_same_roadmap(tmp_path: Path, internal_links: bool) -> None:
    original = load_config(PATROL)
    settings = settings_for_robot(0.3, 1.0, internal_links=internal_links)
    built = build_network(original.roadmap.graph, settings, tmp_path / "cache")
    back = Roadmap.from_net_file(built.net_path)
    assert_same_roadmap(back, original.roadmap)
    assert back.source_net == built.net_path.resolve() and back.source_vclass == "passenger"
    assert back.is_connected()
    assert original.roadmap.source_net is None


def test_a_config_naming_the_network_loads_the_same_roadmap_with_the_path_relative_to_it(
    tmp_path: Path, patrol_doc: dict[str, Any]
) -> None:
    original = load_config(PATROL)
    net = write_network(original.roadmap.graph, tmp_path / "nets" / "w.net.xml", settings_for_robot(0.3, 1.0))
    cfg = load_config(write_config(tmp_path, patrol_doc, {"net": "nets/w.net.xml"}))
    assert_same_roadmap(cfg.roadmap, original.roadmap)
    assert cfg.roadmap.source_net == net.resolve()
    # routes name junction ids and expand along the same shortest paths
    for route in original.routes:
        assert cfg.route(route.name).node_names == route.node_names
        assert cfg.route_poses(cfg.route(route.name)) == pytest.approx(original.route_poses(route))


def test_written_network_header_names_no_temporary_directory(tmp_path: Path) -> None:
    net = write_network(load_config(PATROL).roadmap.graph, tmp_path / "w.net.xml")
    head = net.read_text()[:2000]
    assert 'value="w.nod.xml"' in head and "fleet-net-" not in head


def test_coordinates_are_the_files_own_even_with_a_net_offset(tmp_path: Path) -> None:
    """netconvert without ``--offset.disable-normalization`` shifts the network to the origin
    and records the shift as ``netOffset``; the roadmap keeps the file's coordinates, which are
    the ones SUMO simulates in (netedit and ``build_network`` never shift)."""
    import subprocess
    import xml.etree.ElementTree as ET

    from sim.sumo.net import sumo_binary, write_plain_xml

    g = load_config(PATROL).roadmap.to_networkx()
    nod, edg, _, _ = write_plain_xml(g, tmp_path, "w")
    net = tmp_path / "shifted.net.xml"
    subprocess.run(
        [
            str(sumo_binary("netconvert")),
            "-n",
            str(nod),
            "-e",
            str(edg),
            "-o",
            str(net),
            "--no-internal-links",
        ],
        check=True,
        capture_output=True,
    )
    location = ET.parse(net).getroot().find("location")
    assert location is not None
    dx, dy = (float(v) for v in location.get("netOffset", "").split(","))
    assert (dx, dy) == (-2.5, -2.0)  # the roadmap's lower left node w_p1 moved to (0, 0)
    back = Roadmap.from_net_file(net)
    for n in g.nodes:
        x, y = g.nodes[n]["pos"]
        assert math.dist(back.pos(n), (x + dx, y + dy)) < 0.01

    pytest.importorskip("libsumo")
    import libsumo

    from fleet.clock import SimClock
    from fleet.robots import SimParams
    from sim.sumo.world import SumoWorld

    with SumoWorld(back, [], SimParams(step_s=0.1), SimClock()) as world:
        assert world.network.net_path == net
        for n in back.nodes:
            assert math.dist(libsumo.junction.getPosition(n)[:2], back.pos(n)) < 0.01


def test_a_gzipped_network_reads_like_the_plain_one(tmp_path: Path) -> None:
    import gzip

    (tmp_path / "w.net.xml.gz").write_bytes(gzip.compress(SHIPPED_NET.read_bytes()))
    assert_same_roadmap(Roadmap.from_net_file(tmp_path / "w.net.xml.gz"), Roadmap.from_net_file(SHIPPED_NET))


# ----------------------------------------------------------------------------- the example


def test_the_shipped_example_is_the_patrol_warehouse_on_its_own_network() -> None:
    cfg = load_config(NETXML)
    original = load_config(PATROL)
    assert cfg.roadmap.source_net == SHIPPED_NET.resolve()
    assert cfg.map_path == original.map_path
    assert_same_roadmap(cfg.roadmap, original.roadmap)
    assert [r.name for r in cfg.robots] == [r.name for r in original.robots]
    assert [r.start for r in cfg.robots] == [r.start for r in original.robots]
    assert [r.name for r in cfg.routes] == [r.name for r in original.routes]
    for route in cfg.routes:
        assert route.node_names and all(n is not None and n in cfg.roadmap for n in route.node_names)
        dense = cfg.roadmap.expand_route([n for n in route.node_names if n is not None])
        assert all(b in cfg.roadmap.neighbors(a) for a, b in zip(dense, dense[1:] + dense[:1], strict=True))


def test_the_example_validates_on_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    from fleet.cli.main import main

    assert main(["validate", str(NETXML)]) == 0
    assert "ok" in capsys.readouterr().out


# ----------------------------------------------------------------------------- bad input


def expect(err: ConfigError, path: Path, field: str, *words: str) -> None:
    assert err.file == str(path)
    assert err.field == field
    for w in words:
        assert w in err.reason, (w, err.reason)
    assert str(err).startswith(f"{path}: {field}: ")


def test_a_missing_network_file(tmp_path: Path, patrol_doc: dict[str, Any]) -> None:
    path = write_config(tmp_path, patrol_doc, {"net": "nets/none.net.xml"})
    expect(config_error(path), path, "roadmap.net", "'nets/none.net.xml'", "does not exist", str(tmp_path))


@pytest.mark.parametrize(
    ("content", "words"),
    [
        ("this is not xml <<<", ("not an XML file",)),
        ("", ("not an XML file",)),
        ('<?xml version="1.0"?>\n<routes><vehicle id="v"/></routes>\n', ("not a SUMO network", "<routes>")),
        ("<nodes><node id='a' x='0' y='0'/></nodes>", ("not a SUMO network", "<nodes>", "<net>")),
    ],
    ids=["text", "empty-file", "routes", "plain-nodes"],
)
def test_a_file_that_is_not_a_sumo_network(
    tmp_path: Path, patrol_doc: dict[str, Any], content: str, words: tuple[str, ...]
) -> None:
    (tmp_path / "bad.net.xml").write_text(content)
    path = write_config(tmp_path, patrol_doc, {"net": "bad.net.xml"})
    expect(config_error(path), path, "roadmap.net", "'bad.net.xml'", *words)


def test_a_network_without_edges(tmp_path: Path, patrol_doc: dict[str, Any]) -> None:
    (tmp_path / "empty.net.xml").write_text(
        '<?xml version="1.0"?>\n<net version="1.20">\n'
        '  <location netOffset="0.00,0.00" convBoundary="0,0,1,1" origBoundary="0,0,1,1" projParameter="!"/>\n'
        '  <junction id="a" type="dead_end" x="2.5" y="5.0" incLanes="" intLanes="" shape=""/>\n'
        "</net>\n"
    )
    path = write_config(tmp_path, patrol_doc, {"net": "empty.net.xml"})
    expect(config_error(path), path, "roadmap.net", "'empty.net.xml'", "no edges")


def test_a_network_no_edge_of_which_the_vehicle_class_may_use(
    tmp_path: Path, patrol_doc: dict[str, Any]
) -> None:
    write_network(load_config(PATROL).roadmap.graph, tmp_path / "w.net.xml")
    path = write_config(tmp_path, patrol_doc, {"net": "w.net.xml", "vclass": "pedestrian"})
    assert load_config(path).roadmap.source_vclass == "pedestrian"  # edges allow every class
    text = (tmp_path / "w.net.xml").read_text()
    (tmp_path / "ped.net.xml").write_text(text.replace('<lane id="', '<lane allow="pedestrian" id="'))
    path = write_config(tmp_path, patrol_doc, {"net": "ped.net.xml"})
    expect(config_error(path), path, "roadmap.net", "'ped.net.xml'", "vehicle class 'passenger'")


def test_sumolib_not_installed(
    tmp_path: Path, patrol_doc: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    write_network(load_config(PATROL).roadmap.graph, tmp_path / "w.net.xml")
    for mod in [m for m in sys.modules if m == "sumolib" or m.startswith("sumolib.")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, "sumolib", None)  # import sumolib -> ImportError
    path = write_config(tmp_path, patrol_doc, {"net": "w.net.xml"})
    expect(config_error(path), path, "roadmap.net", "sumolib", "not installed", "make setup-sumo", "[sumo]")


def test_mistakes_in_the_net_form(tmp_path: Path, patrol_doc: dict[str, Any]) -> None:
    write_network(load_config(PATROL).roadmap.graph, tmp_path / "w.net.xml")
    cases: list[tuple[Any, str, str]] = [
        ({"net": "w.net.xml", "vclass": "robott"}, "roadmap.vclass", "unknown SUMO vehicle class 'robott'"),
        ({"net": 3}, "roadmap.net", "must be the path of a SUMO .net.xml file"),
        ({"net": "w.net.xml", "nodes": {"a": [1, 1]}}, "roadmap.nodes", "either net"),
        ({"nett": "w.net.xml"}, "roadmap.nett", "did you mean 'net'?"),
        ({"nodes": patrol_doc["roadmap"]["nodes"], "vclass": "passenger"}, "roadmap.vclass", "roadmap.net"),
    ]
    for roadmap, field, words in cases:
        path = write_config(tmp_path, patrol_doc, roadmap)
        expect(config_error(path), path, field, words)


def test_the_map_checks_apply_to_the_junctions_and_edges_of_a_network(
    tmp_path: Path, patrol_doc: dict[str, Any]
) -> None:
    rm = load_config(PATROL).roadmap
    # a junction inside shelf row 0 (x 4.0..5.0, y 6.5..16.5)
    g = rm.to_networkx()
    g.add_node("inside", pos=(4.5, 10.0))
    g.add_edge("inside", "w_1")
    write_network(g, tmp_path / "shelf.net.xml")
    path = write_config(tmp_path, patrol_doc, {"net": "shelf.net.xml"})
    expect(config_error(path), path, "roadmap.net.junctions.inside", "inside an obstacle")
    # an edge through the shelf row between two free junctions
    g = rm.to_networkx()
    g.add_edge("w_1", "a1_1")
    g.add_edge("a1_1", "a2_2")
    write_network(g, tmp_path / "cut.net.xml")
    path = write_config(tmp_path, patrol_doc, {"net": "cut.net.xml"})
    err = config_error(path)
    assert err.field.startswith("roadmap.net.edges[") and "passes through an obstacle" in err.reason
    # two separate networks
    g = rm.to_networkx()
    g.remove_edges_from([("w_s", "a1_s"), ("w_n", "a1_n"), ("w_p1", "a4_p1")])  # the west column
    write_network(g, tmp_path / "split.net.xml")
    path = write_config(tmp_path, patrol_doc, {"net": "split.net.xml"})
    expect(config_error(path), path, "roadmap", "not connected")


# ----------------------------------------------------------------------------- SUMO run


def test_a_sumo_fleet_patrols_on_the_example_network(tmp_path: Path, zenoh_endpoint: str) -> None:
    pytest.importorskip("libsumo")
    from fleet.cli.main import main
    from sim.sumo.backend import SumoRunnerWorld

    cfg = load_config(NETXML)
    world = SumoRunnerWorld(cfg, list(cfg.robots))
    try:  # the world drives on the example's file, its junctions being the roadmap's nodes
        net = world.world.network
        assert net.net_path == SHIPPED_NET.resolve()
        assert dict(net.junction_of) == {n: n for n in cfg.roadmap.nodes}
        both_ways = {(a, b) for a, b in cfg.roadmap.edges} | {(b, a) for a, b in cfg.roadmap.edges}
        assert set(net.edge_of) == both_ways
    finally:
        world.close()

    report = tmp_path / "report.json"
    code = main(
        ["run", str(NETXML), "--backend", "sumo", "--duration", "120", "--speed", "0", "--no-live",
         "--endpoint", zenoh_endpoint, "--report", str(report)]
    )  # fmt: skip
    assert code == 0
    r = json.loads(report.read_text())
    assert r["backend"] == "sumo"
    assert r["laps_completed"] >= 1
    assert r["collisions"] == 0 and r["deadlocks"] == 0
