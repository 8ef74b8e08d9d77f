"""The site as the task service shows it: the map image, the roadmap, chargers, stations,
routes and parking spots (``GET /api/map``, ``/api/map.png``, ``/api/roadmap`` ...).

Everything is in the ``map`` frame (m, rad). The map image is the occupancy grid drawn as
map_server draws it (free white, occupied black, unknown grey: :mod:`fleet.maps`'s pixels), one pixel per cell, top row
first; ``origin`` is the map's lower-left corner, so pixel ``(col, row)`` covers
``x = origin_x + col * resolution``, ``y = origin_y + (height - 1 - row) * resolution``.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from fleet.maps import FREE, FREE_PIXEL, OCCUPIED_PIXEL, UNKNOWN, UNKNOWN_PIXEL, OccupancyGrid

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig


def map_png(grid: OccupancyGrid) -> bytes:
    """The occupancy grid as a PNG (see the module docstring)."""
    cells = grid.cells
    img = np.full(cells.shape, OCCUPIED_PIXEL, dtype=np.uint8)
    img[cells == FREE] = FREE_PIXEL
    img[cells == UNKNOWN] = UNKNOWN_PIXEL
    mid = (cells > FREE) & (cells < 100)
    img[mid] = (FREE_PIXEL - cells[mid].astype(np.int32) * FREE_PIXEL // 100).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(np.flipud(img), mode="L").save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def map_info(config: FleetConfig) -> dict[str, Any]:
    """``{name, image, resolution, origin: [x, y, 0], width, height, extent: [xmin, xmax,
    ymin, ymax]}`` of the fleet's map (``image``: the PNG's URL path)."""
    g = config.grid
    return {
        "name": config.name,
        "image": "/api/map.png",
        "source": str(config.map_path),
        "resolution": g.resolution,
        "origin": [g.origin_x, g.origin_y, 0.0],
        "width": g.width,
        "height": g.height,
        "extent": list(g.extent),
    }


def roadmap_dict(config: FleetConfig) -> dict[str, Any]:
    """``{nodes: [{name, x, y}], edges: [[a, b]], chargers: [...], stations: [...],
    parking: [...]}`` (the last three as :func:`chargers`, :func:`stations`, :func:`parking`)."""
    rm = config.roadmap
    return {
        "nodes": [{"name": n, "x": rm.pos(n)[0], "y": rm.pos(n)[1]} for n in rm.nodes],
        "edges": [[a, b] for a, b in rm.edges],
        "chargers": chargers(config),
        "stations": stations(config),
        "parking": parking(config),
    }


def _pose(name: str, p: Any) -> dict[str, Any]:
    return {"name": name, "x": p.x, "y": p.y, "theta": p.theta}


def chargers(config: FleetConfig) -> list[dict[str, Any]]:
    """``[{name, x, y, theta}]``."""
    return [_pose(c.name, c.pose) for c in config.chargers]


def stations(config: FleetConfig) -> list[dict[str, Any]]:
    """``[{name, x, y, theta, node}]`` (``node``: the roadmap node nearest the station)."""
    rm = config.roadmap
    return [
        {**_pose(s.name, s.pose), "node": rm.nearest_node(s.pose.x, s.pose.y)}
        for s in config.stations.values()
    ]


def routes(config: FleetConfig) -> list[dict[str, Any]]:
    """``[{name, robot, waypoints: [{x, y, theta}]}]``."""
    return [
        {
            "name": r.name,
            "robot": r.robot,
            "waypoints": [{"x": p.x, "y": p.y, "theta": p.theta} for p in r.waypoints],
        }
        for r in config.routes
    ]


def parking(config: FleetConfig) -> list[dict[str, Any]]:
    """``[{name, x, y, theta}]`` (``parking[i]``)."""
    return [_pose(f"parking[{i}]", p) for i, p in enumerate(config.parking)]
