"""Starting SUMO for a :class:`sim.sumo.world.SumoWorld`: libsumo, the network to drive on,
the command line and the robots' vehicle type.

libsumo is imported lazily (:func:`load_libsumo`), so importing this module never loads it.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import replace
from pathlib import Path
from types import ModuleType
from typing import Any, TypeAlias

import networkx as nx

from fleet.errors import BackendError
from fleet.roadmap.graph import Roadmap
from fleet.robots import RobotModel, SimParams
from sim.sumo.net import SumoNetwork, as_graph, build_network, roadmap_mapping, settings_for_robot

#: The libsumo module (it has no type information: attributes are ``Any``).
Libsumo = ModuleType
#: A roadmap as the SUMO world takes it: a :class:`fleet.roadmap.graph.Roadmap` or its graph.
RoadmapLike: TypeAlias = "Roadmap | nx.Graph[Hashable]"

#: Vehicle type id of the robots.
ROBOT_TYPE = "robot"


def load_libsumo() -> Libsumo:
    """The libsumo module; :class:`BackendError` if it is not installed."""
    try:
        import libsumo
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise BackendError(
            "the SUMO backend needs libsumo: pip install -e '.[sumo]' (or make setup-sumo)"
        ) from exc
    module: Libsumo = libsumo
    return module


def source_net(roadmap: RoadmapLike | None) -> Path | None:
    """The ``.net.xml`` a roadmap (``Roadmap`` or graph) was read from, if any."""
    if roadmap is None:
        return None
    src: Any = getattr(roadmap, "source_net", None)
    if src is None and not hasattr(roadmap, "source_net"):
        try:
            src = as_graph(roadmap).graph.get("sumo_net")
        except TypeError:
            return None
    return Path(src) if src else None


def choose_network(
    roadmap: RoadmapLike,
    model: RobotModel,
    net_file: str | Path | None,
    vclass: str | None,
    cache_dir: str | Path | None,
    internal_links: bool,
) -> tuple[SumoNetwork, nx.Graph[Hashable] | None, str | None]:
    """``(network, mapped graph, vehicle class)``: the network to drive on (``net_file``, the
    file the roadmap was read from, or one generated from the roadmap), the roadmap's graph when
    its nodes are junctions of that file (to map after SUMO starts, :func:`map_roadmap`), and
    the vehicle class (``vclass``, else the roadmap's ``sumo_vclass`` when it was read from the
    file)."""
    source = source_net(roadmap)
    if net_file is None:
        net_file = source
    # the roadmap's nodes are junctions of net_file when the roadmap was read from it
    mapped = (
        as_graph(roadmap)
        if source is not None and net_file is not None and Path(net_file).resolve() == source.resolve()
        else None
    )
    if mapped is not None and vclass is None:
        vclass = mapped.graph.get("sumo_vclass")
    if net_file is not None:
        network = SumoNetwork(net_path=Path(net_file), cached=True)
        if not network.net_path.is_file():
            raise BackendError(f"SUMO network {net_file} does not exist")
    else:
        settings = settings_for_robot(model.radius, model.max_linear_speed, internal_links=internal_links)
        network = build_network(as_graph(roadmap), settings, cache_dir)
    return network, mapped, vclass


def sumo_command(
    net_path: Path,
    params: SimParams,
    begin: float,
    time_to_teleport: float,
    sumo_log: str | Path | None,
    extra: Sequence[str],
) -> list[str]:
    """SUMO's command line: the network, the step, start time ``begin`` (s), the seed,
    collision checks that only count real overlaps (``warn``), teleports after
    ``time_to_teleport`` s (``<= 0``: never), A* routing, then ``extra``. Without
    ``sumo_log`` SUMO's warnings are silenced."""
    return [
        "sumo",
        "--net-file",
        str(net_path),
        "--step-length",
        f"{params.step_s}",
        "--begin",
        f"{begin}",
        "--seed",
        str(int(params.seed)),
        "--no-step-log",
        "true",
        *(["--log", str(sumo_log)] if sumo_log is not None else ["--no-warnings", "true"]),
        "--collision.action",
        "warn",
        "--collision.check-junctions",
        "true",
        "--collision.mingap-factor",
        "0",
        "--time-to-teleport",
        f"{time_to_teleport if time_to_teleport > 0 else -1}",
        "--time-to-teleport.highways",
        "-1",
        "--routing-algorithm",
        "astar",
        *extra,
    ]


def define_robot_type(ls: Libsumo, model: RobotModel, vclass: str | None) -> float:
    """Create the :data:`ROBOT_TYPE` vehicle type: length and width = robot diameter,
    ``maxSpeed`` / ``accel`` / ``decel`` of ``model``, no driver imperfection (deterministic
    runs). Returns the vehicle length (m)."""
    length = 2.0 * model.radius
    vt = ls.vehicletype
    vt.copy("DEFAULT_VEHTYPE", ROBOT_TYPE)
    if vclass:
        vt.setVehicleClass(ROBOT_TYPE, vclass)
    vt.setLength(ROBOT_TYPE, length)
    vt.setWidth(ROBOT_TYPE, length)
    vt.setMinGap(ROBOT_TYPE, max(0.1, 0.5 * model.radius))
    vt.setMaxSpeed(ROBOT_TYPE, model.max_linear_speed)
    vt.setAccel(ROBOT_TYPE, model.max_linear_accel)
    vt.setDecel(ROBOT_TYPE, model.max_linear_accel)
    vt.setEmergencyDecel(ROBOT_TYPE, 2.0 * model.max_linear_accel)
    vt.setImperfection(ROBOT_TYPE, 0.0)
    vt.setTau(ROBOT_TYPE, 0.5)
    # a robot that has waited at a junction accepts smaller gaps to crossing robots rather
    # than waiting for a perfectly free junction (fewer junction deadlocks)
    vt.setImpatience(ROBOT_TYPE, 1.0)
    return length


def map_roadmap(ls: Libsumo, network: SumoNetwork, graph: nx.Graph[Hashable]) -> SumoNetwork:
    """``network`` with ``junction_of`` / ``edge_of`` of a roadmap read from its file."""
    edges = [
        (e, ls.edge.getFromJunction(e), ls.edge.getToJunction(e))
        for e in ls.edge.getIDList()
        if not e.startswith(":")
    ]
    junction_of, edge_of = roadmap_mapping(graph, ls.junction.getIDList(), edges, net=str(network.net_path))
    return replace(network, junction_of=junction_of, edge_of=edge_of)
