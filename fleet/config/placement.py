"""Resizing the fleet of a config (``load_config(path, robots=N)``, ``--robots N``): keep the
first ``N`` listed robots, or add robots on free start spots. Poses in the ``map`` frame (m, rad)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

from fleet.config.checks import NearIndex
from fleet.config.model import NamedPose
from fleet.errors import ConfigError
from fleet.maps import OccupancyGrid
from fleet.roadmap.graph import Roadmap
from fleet.robots import RobotSpec
from fleet.types import Pose2D

#: m, minimum distance of an added robot's start from any other start and from the chargers
#: (at least two robot radii).
PARKING_SPACING = 1.0


def resize_fleet(
    file: str,
    listed: Sequence[RobotSpec],
    n: object,
    *,
    grid: OccupancyGrid,
    roadmap: Roadmap,
    parking: Sequence[Pose2D],
    chargers: Sequence[NamedPose],
    radius: float,
    battery: float,
) -> list[RobotSpec]:
    """The fleet of ``n`` robots made from the ``listed`` robots of config ``file``.

    ``n`` at most the listed count keeps the first ``n``. A larger ``n`` adds robots named
    ``robot<K>`` (the smallest numbers not already used as a name or namespace), namespace
    ``/robot<K>``, battery ``battery``, on the first free spots of :func:`start_candidates`
    that are clear of obstacles by ``radius`` and at least ``max(PARKING_SPACING, 2 * radius)``
    from every other start and every charger. Raises :class:`ConfigError` (field ``robots``)
    if ``n`` is not a positive integer or the spots run out (the reason says how many fit).
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ConfigError(file, "robots", f"override must be a positive integer, got {n!r}")
    if n <= len(listed):
        return list(listed[:n])
    spacing = max(PARKING_SPACING, 2 * radius)
    near = NearIndex(spacing)
    for p in [r.start for r in listed] + [c.pose for c in chargers]:
        near.add(p.x, p.y, 0)
    out = list(listed)
    names = _free_names({r.name for r in listed} | {r.namespace.lstrip("/") for r in listed})
    for spot in start_candidates(roadmap, parking):
        if len(out) == n:
            break
        if near.closer_than(spot.x, spot.y, spacing) is not None or not grid.is_free(spot.x, spot.y, radius):
            continue
        near.add(spot.x, spot.y, 0)
        name = next(names)
        out.append(RobotSpec(name=name, namespace=f"/{name}", start=spot, battery=battery))
    if len(out) < n:
        raise ConfigError(
            file,
            "robots",
            f"cannot place {n} robots: only {len(out)} fit ({len(listed)} listed + {len(out) - len(listed)} "
            f"free start spots at least {spacing:g} m apart)",
        )
    return out


def _free_names(used: set[str]) -> Iterator[str]:
    k = 1
    while True:
        if f"robot{k}" not in used:
            yield f"robot{k}"
        k += 1


def start_candidates(roadmap: Roadmap, parking: Sequence[Pose2D]) -> list[Pose2D]:
    """Parking spots first, then points every :data:`PARKING_SPACING` m along each roadmap
    edge (in roadmap order, facing along the edge)."""
    out = list(parking)
    for a, b in roadmap.edges:
        (ax, ay), (bx, by) = roadmap.pos(a), roadmap.pos(b)
        length = math.hypot(bx - ax, by - ay)
        th = math.atan2(by - ay, bx - ax)
        for s in range(int(length // PARKING_SPACING) + 1):
            t = s * PARKING_SPACING / length if length > 0 else 0.0
            out.append(Pose2D(ax + t * (bx - ax), ay + t * (by - ay), th))
    return out
