"""The warehouse roadmap: a graph of named points (aisle ends, corridor junctions) in the
``map`` frame joined by drivable straight segments.

A :class:`Roadmap` wraps an undirected :class:`networkx.Graph` whose nodes are names (``str``)
with attribute ``pos`` = ``(x, y)`` in meters and whose edges carry ``length`` in meters.
Fleet configs declare it explicitly (``roadmap.nodes`` / ``roadmap.edges``) or name a SUMO
network (``roadmap.net``, a ``.net.xml`` made in netedit, read with sumolib), see
``docs/config.md``; other loaders build a graph and call :meth:`Roadmap.from_graph`. A
roadmap read from a SUMO network remembers the file (:attr:`Roadmap.source_net`) so that the
SUMO backend drives on that very network.

The class is plain and read-only after construction: planning queries (shortest paths, travel
costs, dense loops for patrol routes) never change it, so traffic management can be layered
on top without touching it.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Hashable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TypeVar

import networkx as nx
import numpy as np

from fleet.errors import BackendError, ConfigError
from fleet.types import Pose2D

#: Vehicle class whose edges a ``roadmap.net`` network contributes unless ``vclass`` says otherwise.
DEFAULT_VCLASS = "passenger"

#: How many shortest paths a roadmap remembers (the oldest is forgotten first).
PATH_MEMO = 65536

#: Roadmaps with at least this many nodes answer :meth:`Roadmap.nearest_node` from a grid of
#: buckets (:class:`_NodeGrid`) instead of testing every node: the same node, far faster on the
#: floors of thousands of robots, which ask once per robot and charger.
GRID_FROM_NODES = 256

_Node = TypeVar("_Node", bound=Hashable)


class _NodeGrid:
    """Node positions in square buckets, for the nearest node to a point: the node of least
    squared distance, ties to the lower index, exactly as the whole-array ``argmin`` gives it
    (the candidates' squared distances are the same NumPy expression over the same values).
    """

    def __init__(self, xy: np.ndarray) -> None:
        self.xy = xy
        lo = xy.min(axis=0)
        span = np.maximum(xy.max(axis=0) - lo, 1e-9)
        # about two nodes per bucket
        self.cell = float(max(math.sqrt(float(span[0] * span[1]) * 2.0 / len(xy)), 1e-6))
        self.lo = lo
        self.shape = (int(span[0] // self.cell) + 1, int(span[1] // self.cell) + 1)
        ij = np.minimum(((xy - lo) // self.cell).astype(np.int64), np.array(self.shape) - 1)
        key = ij[:, 0] * self.shape[1] + ij[:, 1]
        order = np.argsort(key, kind="stable")
        self.order = order
        self.starts = np.searchsorted(key[order], np.arange(self.shape[0] * self.shape[1] + 1))
        self._blocks: dict[tuple[int, int], np.ndarray] = {}

    def _block(self, ci: int, cj: int) -> np.ndarray:
        """Indexes (ascending) of the nodes in the 3 x 3 buckets around bucket ``(ci, cj)``."""
        got = self._blocks.get((ci, cj))
        if got is None:
            nx_, ny_ = self.shape
            parts = [
                self.order[self.starts[i * ny_ + j] : self.starts[i * ny_ + j + 1]]
                for i in range(max(0, ci - 1), min(nx_, ci + 2))
                for j in range(max(0, cj - 1), min(ny_, cj + 2))
            ]
            got = self._blocks[(ci, cj)] = np.sort(np.concatenate(parts))
        return got

    def nearest(self, x: float, y: float) -> int:
        """Index of the node nearest ``(x, y)`` (see the class docstring): from the 3 x 3
        buckets around the point when the best of them is nearer than a bucket's width
        (every node outside them is at least that far), else from every node."""
        ci = min(max(int((x - self.lo[0]) // self.cell), 0), self.shape[0] - 1)
        cj = min(max(int((y - self.lo[1]) // self.cell), 0), self.shape[1] - 1)
        idx = self._block(ci, cj)
        if len(idx):
            d2 = (self.xy[idx, 0] - x) ** 2 + (self.xy[idx, 1] - y) ** 2
            k = int(np.argmin(d2))
            if math.sqrt(float(d2[k])) * (1 + 1e-9) + 1e-9 < self.cell:
                return int(idx[k])
        d2 = (self.xy[:, 0] - x) ** 2 + (self.xy[:, 1] - y) ** 2
        return int(np.argmin(d2))


#: The bucketed nearest-node index, for other road indexes over node positions
#: (:class:`fleet.traffic.roads.RoadIndex`): the node the whole-array ``argmin`` gives.
NodeGrid = _NodeGrid


class Roadmap:
    """A read-only roadmap graph. Build it with :meth:`from_config_dict` or :meth:`from_graph`.

    Node order (``nodes``) is the insertion order of the source, so every query that has to
    break a tie (e.g. :meth:`nearest_node`) does so deterministically.
    """

    def __init__(self, graph: nx.Graph[str]) -> None:
        """Wrap ``graph`` as is. Prefer :meth:`from_graph`, which checks the attributes.

        Graph-level attributes are kept: ``graph.graph["sumo_net"]`` (the absolute path of the
        ``.net.xml`` the graph was read from, see :func:`sim.sumo.net.read_network`) becomes
        :attr:`source_net`, ``graph.graph["sumo_vclass"]`` :attr:`source_vclass`.
        """
        self._g = graph
        self._names: list[str] = [str(n) for n in graph.nodes]
        self._xy = (
            np.array([graph.nodes[n]["pos"] for n in graph.nodes], dtype=float).reshape(-1, 2)
            if self._names
            else np.zeros((0, 2))
        )
        #: Shortest paths already found (the graph is read-only): route copies and patrol
        #: loops ask for the same legs again and again. Bounded by :data:`PATH_MEMO`.
        self._paths: dict[tuple[str, str], tuple[str, ...]] = {}
        self._grid: _NodeGrid | None = None  # built on the first nearest-node query of a big roadmap

    # ------------------------------------------------------------------ constructors

    @classmethod
    def from_graph(cls, g: nx.Graph[_Node]) -> Roadmap:
        """Build a roadmap from any undirected graph whose nodes have ``pos`` = ``(x, y)`` (m).

        Node names are converted to ``str``. An edge without ``length`` gets the straight-line
        distance between its end points; an edge's own ``length`` (e.g. a curved lane) is kept.
        Graph-level attributes are copied (so a graph from :func:`sim.sumo.net.read_network`
        keeps its ``sumo_net``: :attr:`source_net`). Raises ``ValueError`` if a node has no
        valid ``pos`` or a length is negative.
        """
        out: nx.Graph[str] = nx.Graph()
        out.graph.update(g.graph)
        for n, data in g.nodes(data=True):
            pos = data.get("pos")
            if pos is None or len(pos) != 2:
                raise ValueError(f"roadmap node {n!r} has no pos (x, y)")
            out.add_node(str(n), **{**data, "pos": (float(pos[0]), float(pos[1]))})
        for a, b, data in g.edges(data=True):
            pa, pb = out.nodes[str(a)]["pos"], out.nodes[str(b)]["pos"]
            length = float(data.get("length", math.dist(pa, pb)))
            if length < 0 or not math.isfinite(length):
                raise ValueError(f"roadmap edge ({a!r}, {b!r}) has invalid length {length}")
            out.add_edge(str(a), str(b), **{**data, "length": length})
        return cls(out)

    @classmethod
    def from_config_dict(
        cls, d: object, file: str = "<memory>", field: str = "roadmap", *, base_dir: str | Path | None = None
    ) -> Roadmap:
        """Build a roadmap from the ``roadmap`` section of a fleet config.

        ``d`` is either ``{"nodes": {name: [x, y], ...}, "edges": [[a, b], ...]}`` (meters, map
        frame) or ``{"net": path, "vclass": cls}``: a SUMO network (see :meth:`from_net_file`)
        whose path is relative to ``base_dir`` (default: the directory of ``file``, the config).
        Raises :class:`ConfigError` naming ``file`` and the offending field (e.g.
        ``roadmap.edges[3]``, ``roadmap.net``) for a wrong shape, a duplicate or self edge, an
        unknown node, or a SUMO network that cannot be used.
        """
        if not isinstance(d, Mapping):
            raise ConfigError(
                file, field, f"must be a mapping with nodes and edges (or net), got {_tname(d)}"
            )
        keys = ("nodes", "edges", "net", "vclass")
        extra = set(d) - set(keys)
        if extra:
            key = sorted(map(str, extra))[0]
            hint = _suggest(key, keys, " (expected nodes and edges, or net)")
            raise ConfigError(file, f"{field}.{key}", f"unknown key{hint}")
        if "net" in d:
            both = sorted(set(d) & {"nodes", "edges"})
            if both:
                raise ConfigError(
                    file,
                    f"{field}.{both[0]}",
                    "give either net (a SUMO network) or nodes and edges, not both",
                )
            base = Path(base_dir) if base_dir is not None else Path(file).parent
            return cls._from_net_section(d, file, field, base)
        if "vclass" in d:
            raise ConfigError(file, f"{field}.vclass", "only applies to a SUMO network (roadmap.net)")
        nodes = d.get("nodes")
        if not isinstance(nodes, Mapping) or not nodes:
            raise ConfigError(file, f"{field}.nodes", "must be a non-empty mapping of name: [x, y]")
        g: nx.Graph[str] = nx.Graph()
        for name, xy in nodes.items():
            f = f"{field}.nodes.{name}"
            if not isinstance(name, str) or not name:
                raise ConfigError(file, f, "node names must be non-empty strings")
            if not (isinstance(xy, (list, tuple)) and len(xy) == 2 and all(_is_number(v) for v in xy)):
                raise ConfigError(file, f, f"must be [x, y] in meters, got {xy!r}")
            g.add_node(name, pos=(float(xy[0]), float(xy[1])))
        edges = d.get("edges", [])
        if not isinstance(edges, list):
            raise ConfigError(file, f"{field}.edges", f"must be a list of [a, b] pairs, got {_tname(edges)}")
        for i, e in enumerate(edges):
            f = f"{field}.edges[{i}]"
            if not (isinstance(e, (list, tuple)) and len(e) == 2):
                raise ConfigError(file, f, f"must be a pair [a, b] of node names, got {e!r}")
            for end in e:
                if not isinstance(end, str) or end not in g:
                    hint = _suggest(str(end), g.nodes) if isinstance(end, str) else ""
                    raise ConfigError(file, f, f"unknown roadmap node {end!r}{hint}")
            a, b = e
            if a == b:
                raise ConfigError(file, f, f"edge joins node {a!r} to itself")
            if g.has_edge(a, b):
                raise ConfigError(file, f, f"duplicate edge between {a!r} and {b!r}")
            g.add_edge(a, b, length=math.dist(g.nodes[a]["pos"], g.nodes[b]["pos"]))
        return cls(g)

    @classmethod
    def _from_net_section(cls, d: Mapping[str, object], file: str, field: str, base: Path) -> Roadmap:
        rel = d["net"]
        if not isinstance(rel, str) or not rel:
            raise ConfigError(file, f"{field}.net", f"must be the path of a SUMO .net.xml file, got {rel!r}")
        vclass = d.get("vclass", DEFAULT_VCLASS)
        if not isinstance(vclass, str) or not vclass:
            raise ConfigError(file, f"{field}.vclass", f"must be a SUMO vehicle class name, got {vclass!r}")
        return cls.from_net_file(base / rel, vclass=vclass, file=file, field=field, shown=rel)

    @classmethod
    def from_net_file(
        cls,
        net_path: str | Path,
        *,
        vclass: str = DEFAULT_VCLASS,
        file: str | None = None,
        field: str = "roadmap",
        shown: str | None = None,
    ) -> Roadmap:
        """Read a SUMO network (``.net.xml``, e.g. drawn in netedit) with sumolib.

        Nodes are the junction ids at the junctions' SUMO ``(x, y)``, which is the ``map`` frame
        (meters); an edge joins two junctions when a SUMO edge that vehicle class ``vclass`` may
        use drives between them, either way; its ``length`` is the SUMO edge's node-to-node
        length (see :func:`sim.sumo.net.read_network`). :attr:`source_net` is the absolute path
        of the file and :attr:`source_vclass` is ``vclass``.

        Raises :class:`ConfigError` with ``file`` (default: the network file itself) and field
        ``<field>.net`` (``<field>.vclass`` for an unknown vehicle class) if the file is missing,
        is not XML or not a SUMO network, has no edge ``vclass`` may use, or sumolib is not
        installed. ``shown`` is how the path appears in messages (default: as given).
        """
        path = Path(net_path)
        src = str(path) if file is None else file
        f = f"{field}.net"
        name = repr(shown if shown is not None else str(net_path))
        if not path.is_file():
            raise ConfigError(
                src, f, f"SUMO network file {name} does not exist (looked for {path.resolve()})"
            )
        try:
            import sumolib.net.lane
        except ImportError:
            raise ConfigError(
                src,
                f,
                f"reading the SUMO network {name} needs sumolib, which is not installed: "
                "run `make setup-sumo` (or pip install -e '.[sumo]')",
            ) from None
        known = sorted(sumolib.net.lane.SUMO_VEHICLE_CLASSES)
        if vclass not in known:
            hint = _suggest(vclass, known, f" (one of {', '.join(known)})")
            raise ConfigError(src, f"{field}.vclass", f"unknown SUMO vehicle class {vclass!r}{hint}")
        from fleet.roadmap.netxml import read_network

        try:
            g = read_network(path, vclass=vclass)
        except ConfigError as e:
            raise ConfigError(src, f, f"{name}: {e.reason}") from None
        except BackendError as e:
            raise ConfigError(src, f, f"{name}: {e}") from None
        try:
            return cls.from_graph(g)
        except ValueError as e:
            raise ConfigError(src, f, f"{name}: {e}") from None

    # ------------------------------------------------------------------ queries

    @property
    def nodes(self) -> list[str]:
        """Node names in source order (a copy)."""
        return list(self._names)

    @property
    def edges(self) -> list[tuple[str, str]]:
        """Undirected edges as ``(a, b)`` pairs in source order (a copy)."""
        return [(str(a), str(b)) for a, b in self._g.edges]

    @property
    def source_net(self) -> Path | None:
        """Absolute path of the SUMO ``.net.xml`` this roadmap was read from, or ``None``.

        The SUMO backend drives on this file instead of generating a network from the graph.
        """
        path = self._g.graph.get("sumo_net")
        return Path(path) if path else None

    @property
    def source_vclass(self) -> str | None:
        """The SUMO vehicle class whose edges were read from :attr:`source_net` (``None`` if the
        roadmap is not from a SUMO network, or every edge was kept)."""
        vc = self._g.graph.get("sumo_vclass")
        return str(vc) if vc else None

    @property
    def graph(self) -> nx.Graph[str]:
        """The underlying graph. Treat it as read-only; use :meth:`to_networkx` to modify a copy."""
        return self._g

    def __contains__(self, name: object) -> bool:
        return name in self._g

    def __len__(self) -> int:
        return len(self._names)

    def pos(self, name: str) -> tuple[float, float]:
        """``(x, y)`` of node ``name`` in meters. Raises ``KeyError`` for an unknown node."""
        if name not in self._g:
            raise KeyError(f"unknown roadmap node {name!r}")
        x, y = self._g.nodes[name]["pos"]
        return (float(x), float(y))

    def neighbors(self, name: str) -> list[str]:
        """Names of the nodes joined to ``name`` by an edge."""
        return [str(n) for n in self._g.neighbors(name)]

    def edge_length(self, a: str, b: str) -> float:
        """Length in meters of edge ``(a, b)``. Raises ``KeyError`` if there is no such edge."""
        if not self._g.has_edge(a, b):
            raise KeyError(f"no roadmap edge between {a!r} and {b!r}")
        return float(self._g.edges[a, b]["length"])

    def nearest_node(self, x: float, y: float) -> str:
        """The node closest (straight line) to ``(x, y)``; ties go to the earlier node.

        Raises ``ValueError`` if the roadmap is empty.
        """
        if not self._names:
            raise ValueError("the roadmap has no nodes")
        if len(self._names) < GRID_FROM_NODES:
            d2 = (self._xy[:, 0] - x) ** 2 + (self._xy[:, 1] - y) ** 2
            return self._names[int(np.argmin(d2))]
        if self._grid is None:
            self._grid = _NodeGrid(self._xy)
        return self._names[self._grid.nearest(x, y)]

    def shortest_path(self, a: str, b: str) -> list[str]:
        """Node names of a shortest path (by edge ``length``) from ``a`` to ``b``, both included.

        Returns ``[a]`` when ``a == b`` and ``[]`` when ``b`` cannot be reached from ``a``.
        Raises ``KeyError`` for an unknown node.
        """
        known = self._paths.get((a, b))
        if known is not None:
            return list(known)
        for n in (a, b):
            if n not in self._g:
                raise KeyError(f"unknown roadmap node {n!r}")
        try:
            path = tuple(str(n) for n in nx.shortest_path(self._g, a, b, weight="length"))
        except nx.NetworkXNoPath:
            path = ()
        if len(self._paths) >= PATH_MEMO:
            self._paths.pop(next(iter(self._paths)))
        self._paths[(a, b)] = path
        return list(path)

    def distance(self, a: str, b: str) -> float:
        """Length in meters of a shortest path from ``a`` to ``b``; ``inf`` if unreachable."""
        path = self.shortest_path(a, b)
        return self.path_length(path) if path else math.inf

    def path_length(self, nodes: Sequence[str]) -> float:
        """Length in meters of the polyline through ``nodes``.

        Consecutive nodes joined by an edge contribute the edge's ``length``; others the
        straight-line distance between them. Fewer than two nodes give ``0.0``.
        """
        total = 0.0
        for a, b in zip(nodes, nodes[1:], strict=False):
            if self._g.has_edge(a, b):
                total += float(self._g.edges[a, b]["length"])
            else:
                total += math.dist(self.pos(a), self.pos(b))
        return total

    def travel_cost(self, from_pose: Pose2D, to_node: str) -> float:
        """Estimated distance in meters to drive from ``from_pose`` to node ``to_node``.

        The straight-line distance from the pose to its nearest node plus the shortest-path
        distance from there to ``to_node``; ``inf`` if ``to_node`` cannot be reached.
        """
        start = self.nearest_node(from_pose.x, from_pose.y)
        sx, sy = self.pos(start)
        return math.hypot(sx - from_pose.x, sy - from_pose.y) + self.distance(start, to_node)

    def expand_route(self, waypoint_nodes: Sequence[str], closed: bool = True) -> list[str]:
        """The dense node sequence that visits ``waypoint_nodes`` in order along shortest paths.

        Consecutive entries of the result are joined by roadmap edges, and no node repeats
        immediately. With ``closed=True`` the result is a loop: it also contains the path from
        the last waypoint back to the first, without repeating the first node at the end (so
        the last node is adjacent to the first, and the sequence can be driven cyclically).
        Raises ``KeyError`` for an unknown node and ``ValueError`` if a leg is unreachable.
        """
        wps = list(waypoint_nodes)
        if not wps:
            return []
        legs = list(zip(wps, wps[1:], strict=False))
        if closed and len(wps) > 1:
            legs.append((wps[-1], wps[0]))
        out: list[str] = [wps[0]]
        if wps[0] not in self._g:
            raise KeyError(f"unknown roadmap node {wps[0]!r}")
        for a, b in legs:
            path = self.shortest_path(a, b)
            if not path:
                raise ValueError(f"no roadmap path from {a!r} to {b!r}")
            for n in path[1:]:
                if n != out[-1]:
                    out.append(n)
        if closed and len(out) > 1 and out[-1] == out[0]:
            out.pop()
        return out

    def poses_for(self, nodes: Sequence[str], closed: bool = False) -> tuple[Pose2D, ...]:
        """Poses at ``nodes`` with ``theta`` pointing along the direction of travel (rad).

        Each pose faces the next node; the last faces the first when ``closed`` is true and
        otherwise keeps the heading of the last leg. A single node gets ``theta = 0``.
        """
        pts = [self.pos(n) for n in nodes]
        out: list[Pose2D] = []
        for i, (x, y) in enumerate(pts):
            if i + 1 < len(pts):
                nx_, ny_ = pts[i + 1]
                theta = math.atan2(ny_ - y, nx_ - x)
            elif closed and len(pts) > 1:
                theta = math.atan2(pts[0][1] - y, pts[0][0] - x)
            elif len(pts) > 1:
                px, py = pts[i - 1]
                theta = math.atan2(y - py, x - px)
            else:
                theta = 0.0
            out.append(Pose2D(x, y, theta))
        return tuple(out)

    def is_connected(self) -> bool:
        """True if every node can reach every other node (an empty roadmap is not connected)."""
        return bool(self._names) and nx.is_connected(self._g)

    def to_networkx(self) -> nx.Graph[str]:
        """A copy of the graph (nodes with ``pos``, edges with ``length``), e.g. for plotting."""
        return self._g.copy()

    def to_config_dict(self) -> dict[str, object]:
        """The ``roadmap`` section that :meth:`from_config_dict` reads back."""
        return {
            "nodes": {n: list(self.pos(n)) for n in self._names},
            "edges": [list(e) for e in self.edges],
        }


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _tname(v: object) -> str:
    return type(v).__name__


def _suggest(word: str, options: Iterable[str], otherwise: str = "") -> str:
    """`` (did you mean 'x'?)`` for the option closest to ``word``, or ``otherwise``."""
    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else otherwise
