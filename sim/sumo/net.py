"""SUMO road networks for the warehouse: roadmap -> ``.net.xml`` and ``.net.xml`` -> graph.

Two directions of conversion:

* :func:`build_network` turns a roadmap (a ``networkx.Graph`` whose nodes carry
  ``pos=(x, y)`` in the ``map`` frame, meters) into a SUMO network. Every roadmap node becomes
  a junction at the same coordinates (no offset: SUMO x/y == map x/y); every undirected
  roadmap edge ``{u, v}`` becomes two one-lane SUMO edges, ``u -> v`` and ``v -> u``, so robots
  can drive an aisle both ways (SUMO drives on the right: the two lanes lie half a lane width
  either side of the aisle's center line). U-turns are allowed at every junction, including
  dead ends and straight-through nodes, because a robot may be sent back the way it came.
  The plain-XML files (``.nod.xml``, ``.edg.xml``) are handed to ``netconvert`` from the
  ``eclipse-sumo`` wheel; the result is cached in a directory keyed by a hash of the inputs,
  so a second build of the same roadmap costs one file lookup.
* :func:`read_network` reads any ``.net.xml`` (for example one drawn in ``netedit``) with
  ``sumolib`` into an undirected ``networkx.Graph`` usable as a roadmap
  (``fleet.roadmap.Roadmap.from_graph``): nodes are the junction ids with ``pos``, edges carry
  ``length``, and ``graph.graph["sumo_net"]`` remembers the file so the SUMO backend drives on
  that very network instead of regenerating one.

Lengths: a junction occupies a small area (about two lane widths across). With junction
internals (``NetSettings.internal_links``), a SUMO lane is shorter than its roadmap edge by the
junction extents at both ends and the lane through the junction makes up the difference; a
straight drive from node to node is as long in SUMO as in the roadmap. Without them (the SUMO
backend's default) netconvert gives each lane its full node-to-node length, drawn between the
junction borders.

This module imports ``sumolib`` and the ``sumo`` wheel lazily; importing it is cheap and never
starts SUMO."""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import networkx as nx

from fleet.errors import BackendError, ConfigError

#: Characters allowed in SUMO ids generated from roadmap node names.
_SAFE_ID = re.compile(r"^[A-Za-z0-9_.\-]+$")


#: Bumped whenever the generated XML or the netconvert options change meaning.
_FORMAT_VERSION = "1"


def sumo_home() -> Path:
    """Directory of the ``eclipse-sumo`` wheel (SUMO_HOME). Raises :class:`BackendError` if absent."""
    try:
        import sumo
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise BackendError(
            "the SUMO backend needs the eclipse-sumo wheel: pip install -e '.[sumo]' (or make setup-sumo)"
        ) from exc
    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> Path:
    """Path of a SUMO program (``netconvert``, ``sumo``, ``netedit`` ...) from the wheel's ``bin``."""
    path = sumo_home() / "bin" / name
    if not path.exists():
        raise BackendError(f"SUMO program {name!r} not found at {path}")
    return path


def default_cache_dir() -> Path:
    """``$FLEET_SUMO_CACHE`` or ``$XDG_CACHE_HOME/fleet-orchestrator/sumo`` (``~/.cache`` default)."""
    env = os.environ.get("FLEET_SUMO_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "fleet-orchestrator" / "sumo"


@dataclass(frozen=True)
class NetSettings:
    """How a roadmap becomes a SUMO network.

    ``lane_width`` (m) and ``speed`` (m/s, the lane speed limit) usually come from the robot
    model (:func:`settings_for_robot`). ``junction_radius`` (m) bounds the junction area;
    ``internal_links=False`` makes vehicles jump across junctions (about twice as fast for
    very large fleets, but junction conflicts are no longer modelled).
    """

    lane_width: float = 0.9
    speed: float = 1.0
    junction_radius: float = 0.9
    internal_links: bool = True
    junction_type: str | None = None

    def netconvert_options(self) -> list[str]:
        opts = [
            "--offset.disable-normalization",
            "true",
            "--no-turnarounds",
            "false",
            "--no-turnarounds.geometry",
            "false",
            "--default.junctions.radius",
            f"{self.junction_radius:.3f}",
            "--junctions.corner-detail",
            "0",
            "--no-warnings",
            "true",
        ]
        if not self.internal_links:
            opts += ["--no-internal-links", "true"]
        if self.junction_type:
            opts += ["--default.junctions.type", self.junction_type]
        return opts


def settings_for_robot(radius: float, max_speed: float, *, internal_links: bool = True) -> NetSettings:
    """Network settings for robots of ``radius`` m driving at most ``max_speed`` m/s:
    lanes ``2 * radius + 0.3`` m wide, junction radius half a lane width."""
    if radius <= 0 or max_speed <= 0:
        raise ValueError(f"radius and max_speed must be positive (got {radius}, {max_speed})")
    width = 2.0 * radius + 0.3
    return NetSettings(
        lane_width=width, speed=max_speed, junction_radius=width / 2.0, internal_links=internal_links
    )


@dataclass(frozen=True)
class SumoNetwork:
    """A built SUMO network and how it relates to the roadmap it came from.

    ``junction_of`` maps each roadmap node to its SUMO junction id; ``edge_of`` maps a
    directed roadmap pair ``(u, v)`` to the SUMO edge id driving from ``u`` to ``v``.
    """

    net_path: Path
    junction_of: Mapping[Hashable, str] = field(default_factory=dict)
    edge_of: Mapping[tuple[Hashable, Hashable], str] = field(default_factory=dict)
    cached: bool = False


def _node_pos(graph: nx.Graph[Hashable], node: Hashable, source: str) -> tuple[float, float]:
    pos = graph.nodes[node].get("pos")
    if pos is None or len(pos) < 2:
        raise ConfigError(source, f"roadmap.nodes.{node}", "node has no 'pos' (x, y) attribute")
    x, y = float(pos[0]), float(pos[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ConfigError(source, f"roadmap.nodes.{node}", f"position ({x}, {y}) is not finite")
    return x, y


def junction_ids(graph: nx.Graph[Hashable]) -> dict[Hashable, str]:
    """SUMO junction id of each roadmap node: the node's name when every name is a safe SUMO
    id (letters, digits, ``_ . -``), otherwise ``n0, n1, ...`` in the graph's node order."""
    names = [str(n) for n in graph.nodes]
    if all(_SAFE_ID.match(s) for s in names) and len(set(names)) == len(names):
        return {n: str(n) for n in graph.nodes}
    return {n: f"n{i}" for i, n in enumerate(graph.nodes)}


def write_plain_xml(
    graph: nx.Graph[Hashable],
    out_dir: Path,
    prefix: str = "roadmap",
    settings: NetSettings | None = None,
    *,
    source: str = "<roadmap>",
) -> tuple[Path, Path, dict[Hashable, str], dict[tuple[Hashable, Hashable], str]]:
    """Write ``<prefix>.nod.xml`` and ``<prefix>.edg.xml`` for ``graph`` into ``out_dir``.

    Returns ``(nod_path, edg_path, junction_of, edge_of)``. Raises :class:`ConfigError`
    (naming ``source``) for a node without a position, a self loop or a zero-length edge.
    """
    settings = settings or NetSettings()
    out_dir.mkdir(parents=True, exist_ok=True)
    jid = junction_ids(graph)
    nod_lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<nodes>"]
    for node in graph.nodes:
        x, y = _node_pos(graph, node, source)
        nod_lines.append(f'    <node id={quoteattr(jid[node])} x="{x:.4f}" y="{y:.4f}"/>')
    nod_lines.append("</nodes>")
    edg_lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<edges>"]
    edge_of: dict[tuple[Hashable, Hashable], str] = {}
    for u, v in graph.edges:
        if u == v:
            raise ConfigError(source, f"roadmap.edges[{u}, {v}]", "self loops cannot become SUMO edges")
        pu, pv = _node_pos(graph, u, source), _node_pos(graph, v, source)
        if math.dist(pu, pv) < 1e-6:
            raise ConfigError(source, f"roadmap.edges[{u}, {v}]", "both ends are at the same position")
        for a, b in ((u, v), (v, u)):
            eid = f"{jid[a]}__{jid[b]}"
            edge_of[(a, b)] = eid
            edg_lines.append(
                f"    <edge id={quoteattr(eid)} from={quoteattr(jid[a])} to={quoteattr(jid[b])} "
                f'numLanes="1" speed="{settings.speed:.3f}" width="{settings.lane_width:.3f}"/>'
            )
    edg_lines.append("</edges>")
    nod_path = out_dir / f"{prefix}.nod.xml"
    edg_path = out_dir / f"{prefix}.edg.xml"
    nod_path.write_text("\n".join(nod_lines) + "\n", encoding="utf-8")
    edg_path.write_text("\n".join(edg_lines) + "\n", encoding="utf-8")
    return nod_path, edg_path, jid, edge_of


def run_netconvert(
    nod_path: Path, edg_path: Path, net_path: Path, settings: NetSettings, *, cwd: Path | None = None
) -> None:
    """Run ``netconvert`` on plain-XML node and edge files (relative paths are relative to
    ``cwd``, default the current directory); raise :class:`BackendError` with netconvert's own
    message if it fails."""
    cmd = [
        str(sumo_binary("netconvert")),
        "--node-files",
        str(nod_path),
        "--edge-files",
        str(edg_path),
        "--output-file",
        str(net_path),
        *settings.netconvert_options(),
    ]
    env = dict(os.environ)
    env.setdefault("SUMO_HOME", str(sumo_home()))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False, cwd=cwd)
    if proc.returncode != 0 or not (cwd / net_path if cwd is not None else net_path).exists():
        raise BackendError(
            f"netconvert failed (exit {proc.returncode}) for {edg_path}: {proc.stderr.strip() or proc.stdout.strip()}"
        )


def build_network(
    graph: nx.Graph[Hashable],
    settings: NetSettings | None = None,
    cache_dir: Path | str | None = None,
    *,
    source: str = "<roadmap>",
) -> SumoNetwork:
    """Build (or fetch from the cache) the SUMO network of roadmap ``graph``.

    The cache key is a SHA-256 of the generated plain XML, the netconvert options and the
    SUMO version, so any change of node position, edge, lane width or speed builds anew.
    ``cache_dir`` defaults to :func:`default_cache_dir`. Entries are written atomically
    (safe for parallel test workers). If ``graph.graph["sumo_net"]`` names an existing
    ``.net.xml`` (the graph was read by :func:`read_network`), that file is used as is.
    """
    settings = settings or NetSettings()
    existing = graph.graph.get("sumo_net")
    if existing:
        net_path = Path(existing)
        if not net_path.exists():
            raise ConfigError(source, "roadmap", f"SUMO network {net_path} does not exist")
        jid = {n: str(n) for n in graph.nodes}
        return SumoNetwork(net_path=net_path, junction_of=jid, edge_of={}, cached=True)

    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache, prefix=".build-") as tmp:
        tmpdir = Path(tmp)
        nod, edg, jid, edge_of = write_plain_xml(graph, tmpdir, "roadmap", settings, source=source)
        h = hashlib.sha256()
        h.update(_FORMAT_VERSION.encode())
        h.update(_sumo_version().encode())
        h.update(" ".join(settings.netconvert_options()).encode())
        h.update(nod.read_bytes())
        h.update(edg.read_bytes())
        key = h.hexdigest()[:20]
        final = cache / f"{key}.net.xml"
        if final.exists():
            return SumoNetwork(net_path=final, junction_of=jid, edge_of=edge_of, cached=True)
        out = tmpdir / "roadmap.net.xml"
        run_netconvert(nod, edg, out, settings)
        shutil.copy(nod, cache / f"{key}.nod.xml")
        shutil.copy(edg, cache / f"{key}.edg.xml")
        os.replace(out, final)
    return SumoNetwork(net_path=final, junction_of=jid, edge_of=edge_of, cached=False)


def _sumo_version() -> str:
    try:
        import importlib.metadata

        return importlib.metadata.version("eclipse-sumo")
    except Exception:  # pragma: no cover - depends on the install
        return "unknown"


def roadmap_mapping(
    graph: nx.Graph[Hashable],
    junctions: Iterable[str],
    edges: Iterable[tuple[str, str, str]],
    *,
    net: str = "<net>",
) -> tuple[dict[Hashable, str], dict[tuple[Hashable, Hashable], str]]:
    """Map the nodes and edges of a roadmap read from a SUMO network onto that network.

    ``junctions`` are the network's junction ids, ``edges`` its ``(edge id, from junction, to
    junction)`` triples (non-internal). Returns ``(junction_of, edge_of)`` as in
    :class:`SumoNetwork`: each roadmap node is the junction of the same id; ``(u, v)`` maps to
    a SUMO edge driving ``u -> v`` (the first in ``edges`` order when there are parallel
    ones); a direction no SUMO edge drives (a one-way street) is absent. Raises
    :class:`BackendError` (naming ``net``) if a roadmap node is not a junction of the network.
    """
    ids = set(junctions)
    junction_of: dict[Hashable, str] = {}
    for n in graph.nodes:
        if str(n) not in ids:
            raise BackendError(
                f"roadmap node {n!r} is not a junction of the SUMO network {net}: "
                "the roadmap was not read from this network"
            )
        junction_of[n] = str(n)
    edge_of: dict[tuple[Hashable, Hashable], str] = {}
    for eid, a, b in edges:
        if graph.has_edge(a, b) and (a, b) not in edge_of:
            edge_of[(a, b)] = eid
    return junction_of, edge_of


def write_network(
    graph: nx.Graph[Hashable], out_path: Path | str, settings: NetSettings | None = None
) -> Path:
    """Write the SUMO network of roadmap ``graph`` to ``out_path`` (a ``.net.xml``), bypassing
    the cache: e.g. to edit it in netedit or ship it with a config (``roadmap: {net: ...}``).

    The network is the one :func:`build_network` makes with the same ``settings``. The
    header comment netconvert writes names the plain-XML inputs by their bare file names.
    Raises :class:`BackendError` if netconvert fails, :class:`ConfigError` for a bad roadmap.
    """
    settings = settings or NetSettings()
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    stem = out.name.removesuffix(".xml").removesuffix(".net") or "roadmap"
    with tempfile.TemporaryDirectory(prefix="fleet-net-") as tmp:
        tmpdir = Path(tmp)
        nod, edg, _, _ = write_plain_xml(graph, tmpdir, stem, settings)
        built = tmpdir / f"{stem}.net.xml"
        run_netconvert(Path(nod.name), Path(edg.name), Path(built.name), settings, cwd=tmpdir)
        shutil.copy(built, out)
    return out


def grid_roadmap(
    nx_cols: int, ny_rows: int, spacing: float = 20.0, origin: tuple[float, float] = (0.0, 0.0)
) -> nx.Graph[Hashable]:
    """A rectangular grid roadmap of ``nx_cols x ny_rows`` nodes, ``spacing`` m apart, nodes
    named ``g<col>_<row>``; for benchmarks and tests."""
    g: nx.Graph[Hashable] = nx.Graph()
    for i in range(nx_cols):
        for j in range(ny_rows):
            g.add_node(f"g{i}_{j}", pos=(origin[0] + i * spacing, origin[1] + j * spacing))
    for i in range(nx_cols):
        for j in range(ny_rows):
            if i + 1 < nx_cols:
                g.add_edge(f"g{i}_{j}", f"g{i + 1}_{j}", length=spacing)
            if j + 1 < ny_rows:
                g.add_edge(f"g{i}_{j}", f"g{i}_{j + 1}", length=spacing)
    return g


def as_graph(roadmap: object) -> nx.Graph[Hashable]:
    """The ``networkx.Graph`` of a roadmap given either as a graph or as an object wrapping one
    (``fleet.roadmap.Roadmap``: attribute ``graph``)."""
    if isinstance(roadmap, nx.Graph):
        return roadmap
    for attr in ("graph", "g", "_graph", "nx"):
        g = getattr(roadmap, attr, None)
        if isinstance(g, nx.Graph):
            return g
    raise TypeError(f"expected a networkx.Graph or a Roadmap wrapping one, got {type(roadmap).__name__}")


def main(argv: list[str] | None = None) -> int:
    """``python -m sim.sumo.net CONFIG OUT.net.xml``: write the SUMO network of a fleet config's
    roadmap, as the SUMO backend would build it, to a file (to edit in netedit, or to ship with
    a config as ``roadmap: {net: ...}``)."""
    import argparse

    from fleet.config.loader import load_config
    from fleet.errors import FleetError

    p = argparse.ArgumentParser(
        prog="python -m sim.sumo.net",
        description="Write the SUMO network (.net.xml) of a fleet config's roadmap: one junction per "
        "roadmap node at its map (x, y), two one-lane edges per roadmap edge, lanes as wide and as "
        "fast as the config's robot_model allows, U-turns everywhere. Open the result in netedit "
        "and use it as `roadmap: {net: FILE}` (docs/sumo.md).",
        epilog="Example: python -m sim.sumo.net configs/warehouse_patrol.yaml configs/nets/warehouse_small.net.xml",
    )
    p.add_argument("config", help="fleet config YAML whose roadmap to convert")
    p.add_argument("out", help="output .net.xml")
    p.add_argument(
        "--internal-links",
        action="store_true",
        help="model lanes inside junctions (off by default, like the SUMO backend; see docs/sumo.md)",
    )
    a = p.parse_args(argv)
    try:
        cfg = load_config(a.config)
        m = cfg.sim.model
        settings = settings_for_robot(m.radius, m.max_linear_speed, internal_links=a.internal_links)
        out = write_network(as_graph(cfg.roadmap), a.out, settings)
    except FleetError as e:
        print(f"error: {e}")
        return 2
    print(f"wrote {out}: {len(cfg.roadmap)} junctions, {2 * len(cfg.roadmap.edges)} edges")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
