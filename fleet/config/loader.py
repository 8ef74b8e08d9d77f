"""Loading a fleet config file: :func:`load_config` (format: ``docs/config.md``).

Three stages, each raising a :class:`~fleet.errors.ConfigError` ``<file>: <field>: <reason>``
for the first problem it finds: the YAML text (:func:`read_document`), the schema (shape,
types, ranges, names: :mod:`fleet.config.schema`), then the checks that need the map and the
roadmap (:mod:`fleet.config.checks`, and :mod:`fleet.config.placement` for ``robots=N``).
Problems inside the map files raise :class:`~fleet.errors.MapError` (a ``ConfigError``)
naming the map file.

All poses are in the ``map`` frame: meters and radians. Paths inside a config are relative to
the config file.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from fleet.config.checks import (
    Placer,
    References,
    check_roadmap,
    check_station_names,
    listed_robots,
    named_poses,
)
from fleet.config.model import FleetConfig
from fleet.config.placement import resize_fleet
from fleet.config.schema import ConfigFile, validate_document
from fleet.errors import ConfigError, MapError
from fleet.maps import load_map
from fleet.roadmap.graph import Roadmap
from fleet.yamlfile import YamlProblem, parse_yaml


def load_config(path: str | Path, *, robots: int | None = None) -> FleetConfig:
    """Load and validate the fleet config at ``path``.

    ``robots=N`` overrides the robot count: the first ``N`` listed robots are kept, and if
    ``N`` is larger, robots ``robot<K>`` (the next unused numbers) are added on free start
    spots: first the file's ``parking`` spots, then points every 1 m along roadmap edges,
    each at least 1 m from every other start and from the chargers. Raises
    :class:`ConfigError` for any invalid field (see ``docs/config.md`` for the checks) and
    with field ``robots`` if ``N`` robots do not fit (the reason says how many do).
    """
    p = Path(path)
    file = str(path)
    spec = validate_document(read_document(p, file), file)
    return _build(p, file, spec, robots)


def read_document(p: Path, file: str) -> object:
    """The YAML document in ``p`` (plain Python values); ``file`` is how errors name it."""
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise ConfigError(file, "", "config file does not exist") from None
    except (IsADirectoryError, UnicodeDecodeError, PermissionError) as e:
        raise ConfigError(file, "", f"cannot read config file ({e})") from None
    try:
        return parse_yaml(text)
    except YamlProblem as e:
        raise ConfigError(file, e.field, e.reason) from None
    except yaml.YAMLError as e:
        raise ConfigError(file, "", f"not valid YAML ({_yaml_problem(e)})") from None


def _yaml_problem(e: yaml.YAMLError) -> str:
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    if mark is not None:
        return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    return str(problem)


def _build(p: Path, file: str, spec: ConfigFile, n_robots: int | None) -> FleetConfig:
    """The :class:`FleetConfig` of ``spec`` (which passed the schema) after the map checks."""
    map_path = (p.parent / spec.map).resolve()
    if not map_path.is_file():
        raise ConfigError(file, "map", f"map file {spec.map!r} does not exist (looked for {map_path})")
    try:
        grid = load_map(map_path)
    except MapError as e:
        if e.file != str(map_path) or e.field:
            raise
        raise MapError(file, "map", f"{spec.map!r}: {e.reason}") from None
    place = Placer(file, grid, spec.robot_model.radius)
    roadmap = Roadmap.from_config_dict(spec.roadmap.to_dict(), file, base_dir=p.parent)
    check_roadmap(place, roadmap, spec.roadmap.edges)
    chargers = named_poses(place, spec.chargers, "chargers")
    stations = {s.name: s for s in named_poses(place, spec.stations, "stations")}
    check_station_names(file, stations, roadmap)
    parking = [place.pose(xyz, f"parking[{i}]") for i, xyz in enumerate(spec.parking)]
    fleet = listed_robots(place, spec.robots, spec.battery.initial)
    if n_robots is not None:
        fleet = resize_fleet(
            file,
            fleet,
            n_robots,
            grid=grid,
            roadmap=roadmap,
            parking=parking,
            chargers=chargers,
            radius=place.radius,
            battery=spec.battery.initial,
        )
    refs = References(place, roadmap, stations, {r.name for r in fleet})
    return FleetConfig(
        name=spec.name,
        path=p,
        map_path=map_path,
        grid=grid,
        roadmap=roadmap,
        chargers=chargers,
        stations=stations,
        routes=[refs.route(r, f"routes[{i}]") for i, r in enumerate(spec.routes)],
        tasks=[refs.task(t, f"tasks[{i}]") for i, t in enumerate(spec.tasks)],
        robots=fleet,
        sim=spec.sim_params(tuple(c.pose for c in chargers)),
        tick_hz=spec.agent.tick_hz,
        heartbeat_s=spec.agent.heartbeat_s,
        coordinator=spec.coordinator.to_params(),
        endpoint=spec.bus.endpoint,
        status_hz=spec.bus.status_hz,
        secure=(p.parent / spec.bus.secure).resolve() if spec.bus.secure else None,
        link_timeout_s=spec.bus.link_timeout_s,
        reconnect_s=spec.bus.reconnect_s,
        status_max_period_s=spec.bus.status_max_period_s,
        status_batch=spec.bus.status_batch,
        parking=parking,
        traffic=spec.traffic.to_settings(),
    )
