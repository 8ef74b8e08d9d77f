"""Reading a SUMO network (``.net.xml``, e.g. drawn in netedit) as a roadmap graph with sumolib.

sumolib is imported only when a network is read (``make setup-sumo`` installs it)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import networkx as nx

from fleet.errors import BackendError, ConfigError


def _polyline_length(points: list[tuple[float, float]]) -> float:
    return sum(math.dist(a, b) for a, b in zip(points, points[1:], strict=False))


def _xy(coord: Sequence[float]) -> tuple[float, float]:
    return (float(coord[0]), float(coord[1]))


def _root_tag(path: Path) -> str:
    """The tag of the first element of XML file ``path`` (plain or gzip-compressed); raises
    ``ValueError`` with the parser's message if the file is not well-formed XML."""
    import gzip
    import xml.etree.ElementTree as ET

    with path.open("rb") as raw:
        gz = raw.read(2) == b"\x1f\x8b"
    try:
        with gzip.open(path, "rb") if gz else path.open("rb") as f:
            for _, elem in ET.iterparse(f, events=("start",)):
                return str(elem.tag)
    except (ET.ParseError, OSError, EOFError) as exc:
        raise ValueError(str(exc)) from None
    raise ValueError("no XML element")  # pragma: no cover - iterparse raises on empty input


def read_network(net_path: Path | str, *, vclass: str | None = "passenger") -> nx.Graph[str]:
    """Read a SUMO ``.net.xml`` (or ``.net.xml.gz``) into an undirected roadmap graph.

    Nodes are junction ids (internal and dead-end-only junctions included when an edge touches
    them) with ``pos=(x, y)``: the junction's coordinates in the file, which are the coordinates
    SUMO simulates in (``map`` frame). ``netOffset`` is not undone: netedit and
    :func:`build_network` keep the coordinates they were given (no offset normalization), so
    the file's coordinates are the map's. An edge ``{u, v}`` exists when a SUMO edge drives
    ``u -> v`` or ``v -> u`` (one-way streets become two-way in the roadmap; the SUMO backend
    still drives them one way); it lists those SUMO edges in ``sumo_edges``. ``length`` is the
    node-to-node length: the straight distance, scaled by how much the edge's own shape is
    longer than its chord (curved edges drawn in netedit). Edges that ``vclass`` may not use
    (e.g. sidewalks) are left out; ``vclass=None`` keeps them all.

    ``graph.graph["sumo_net"]`` is the absolute path of the file and
    ``graph.graph["sumo_vclass"]`` the ``vclass`` used. Raises :class:`ConfigError` naming the
    file if it is missing, is not XML, is not a SUMO network (root element other than
    ``<net>``) or has no edge ``vclass`` may use; :class:`BackendError` if sumolib is missing.
    """
    path = Path(net_path)
    if not path.is_file():
        raise ConfigError(str(path), "", "SUMO network file does not exist")
    try:
        import sumolib
    except ImportError as exc:
        raise BackendError(
            "reading a .net.xml needs sumolib: make setup-sumo (or pip install -e '.[sumo]')"
        ) from exc
    try:
        root = _root_tag(path)
    except ValueError as exc:
        raise ConfigError(str(path), "", f"not an XML file ({exc})") from None
    if root != "net":
        raise ConfigError(str(path), "", f"not a SUMO network: the root element is <{root}>, expected <net>")
    try:
        net = sumolib.net.readNet(str(path), withInternal=False)
    except Exception as exc:
        raise ConfigError(str(path), "", f"not a readable SUMO network ({exc})") from exc
    g: nx.Graph[str] = nx.Graph()
    g.graph["sumo_net"] = str(path.resolve())
    g.graph["sumo_vclass"] = vclass
    n_edges = 0
    for edge in net.getEdges(withInternal=False):
        if edge.getFunction() in ("internal", "crossing", "walkingarea"):
            continue
        n_edges += 1
        if vclass is not None and not edge.allows(vclass):
            continue
        u, v = edge.getFromNode(), edge.getToNode()
        if u.getID() == v.getID():
            continue
        pu = _xy(u.getCoord())
        pv = _xy(v.getCoord())
        chord = math.dist(pu, pv)
        shape = [_xy(p) for p in edge.getShape()]
        shape_len = _polyline_length(shape)
        shape_chord = math.dist(shape[0], shape[-1]) if len(shape) > 1 else 0.0
        factor = shape_len / shape_chord if shape_chord > 1e-6 else 1.0
        length = chord * max(1.0, factor)
        for n, p in ((u.getID(), pu), (v.getID(), pv)):
            if n not in g:
                g.add_node(n, pos=p)
        a, b = u.getID(), v.getID()
        if g.has_edge(a, b):
            g.edges[a, b]["length"] = min(g.edges[a, b]["length"], length)
            g.edges[a, b]["sumo_edges"].append(edge.getID())
        else:
            g.add_edge(a, b, length=length, sumo_edges=[edge.getID()])
    if g.number_of_edges() == 0:
        if n_edges == 0:
            reason = "the SUMO network has no edges"
        elif vclass is None:
            reason = "the SUMO network has no edges between two different junctions"
        else:
            reason = (
                f"the SUMO network has no edge that vehicle class {vclass!r} may use "
                f"({n_edges} edges, none allowing {vclass!r})"
            )
        raise ConfigError(str(path), "", reason)
    return g
