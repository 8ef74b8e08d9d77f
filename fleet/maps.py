"""Occupancy grids in the Nav2 ``map_server`` format (a YAML file plus a PGM image).

YAML keys read: ``image`` (path relative to the YAML file), ``resolution`` (m/cell),
``origin`` ([x, y, yaw] of the lower-left pixel in the ``map`` frame), ``negate`` (0/1),
``occupied_thresh``, ``free_thresh`` and ``mode`` (only ``trinary``, the default, is
supported). Interpretation follows map_server: with ``negate: 0`` a pixel value ``v`` gives
occupancy ``p = (255 - v) / 255``; ``p > occupied_thresh`` is occupied, ``p < free_thresh``
is free, anything between is unknown (treated as not traversable).

Row 0 of the image is the top of the map (largest ``y``); :class:`OccupancyGrid` stores
rows bottom-up so that ``cells[iy, ix]`` is the cell containing world point
``(origin_x + (ix + 0.5) * res, origin_y + (iy + 0.5) * res)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from fleet.errors import MapError

FREE = 0
OCCUPIED = 100
UNKNOWN = -1


@dataclass
class OccupancyGrid:
    """A 2-D occupancy grid: ``cells[iy, ix]`` in {FREE, OCCUPIED, UNKNOWN}, rows bottom-up."""

    cells: np.ndarray
    resolution: float
    origin_x: float
    origin_y: float
    source: str = "<memory>"

    @property
    def width(self) -> int:
        return int(self.cells.shape[1])

    @property
    def height(self) -> int:
        return int(self.cells.shape[0])

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of the map in meters."""
        return (
            self.origin_x,
            self.origin_x + self.width * self.resolution,
            self.origin_y,
            self.origin_y + self.height * self.resolution,
        )

    def world_to_cell(self, x: float, y: float) -> tuple[int, int]:
        """Return ``(ix, iy)`` of the cell containing ``(x, y)`` (may be outside the grid)."""
        return (
            int(math.floor((x - self.origin_x) / self.resolution)),
            int(math.floor((y - self.origin_y) / self.resolution)),
        )

    def cell_to_world(self, ix: int, iy: int) -> tuple[float, float]:
        """Center of cell ``(ix, iy)`` in meters."""
        return (
            self.origin_x + (ix + 0.5) * self.resolution,
            self.origin_y + (iy + 0.5) * self.resolution,
        )

    def in_bounds(self, x: float, y: float) -> bool:
        ix, iy = self.world_to_cell(x, y)
        return 0 <= ix < self.width and 0 <= iy < self.height

    def is_free(self, x: float, y: float, radius: float = 0.0) -> bool:
        """True if every cell within ``radius`` meters of ``(x, y)`` is inside the map and free."""
        if radius <= 0.0:
            ix, iy = self.world_to_cell(x, y)
            return 0 <= ix < self.width and 0 <= iy < self.height and self.cells[iy, ix] == FREE
        r = int(math.ceil(radius / self.resolution))
        cx, cy = self.world_to_cell(x, y)
        x0, x1, y0, y1 = cx - r, cx + r + 1, cy - r, cy + r + 1
        if x0 < 0 or y0 < 0 or x1 > self.width or y1 > self.height:
            return False
        ys, xs = np.mgrid[y0:y1, x0:x1]
        wx = self.origin_x + (xs + 0.5) * self.resolution - x
        wy = self.origin_y + (ys + 0.5) * self.resolution - y
        mask = wx * wx + wy * wy <= (radius + 0.5 * self.resolution) ** 2
        return bool(np.all(self.cells[y0:y1, x0:x1][mask] == FREE))


def read_pgm(path: Path) -> np.ndarray:
    """Read a binary (P5) or ASCII (P2) 8-bit PGM image; returns rows top-down (uint8)."""
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if pos < len(data) and data[pos : pos + 1] == b"#":
            while pos < len(data) and data[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace():
            pos += 1
        if start == pos:
            raise ValueError("truncated PGM header")
        tokens.append(data[start:pos])
    magic, w, h, maxval = tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    if maxval != 255:
        raise ValueError(f"only 8-bit PGM is supported (maxval {maxval})")
    if magic == b"P5":
        raw = np.frombuffer(data, dtype=np.uint8, count=w * h, offset=pos + 1)
    elif magic == b"P2":
        raw = np.array(data[pos:].split()[: w * h], dtype=np.uint8)
    else:
        raise ValueError(f"not a PGM image (magic {magic!r})")
    if raw.size != w * h:
        raise ValueError(f"PGM has {raw.size} pixels, header says {w}x{h}")
    return raw.reshape(h, w)


def write_pgm(path: Path, image: np.ndarray) -> None:
    """Write ``image`` (uint8, rows top-down) as a binary PGM."""
    h, w = image.shape
    with open(path, "wb") as f:
        f.write(f"P5\n{w} {h}\n255\n".encode())
        f.write(np.ascontiguousarray(image, dtype=np.uint8).tobytes())


def load_map(yaml_path: str | Path) -> OccupancyGrid:
    """Load a map_server YAML + PGM map. Raises :class:`MapError` naming the file and field."""
    yaml_path = Path(yaml_path)
    src = str(yaml_path)
    try:
        meta = yaml.safe_load(yaml_path.read_text())
    except FileNotFoundError:
        raise MapError(src, "", "map file does not exist") from None
    except yaml.YAMLError as e:
        raise MapError(src, "", f"not valid YAML ({e})") from None
    if not isinstance(meta, dict):
        raise MapError(src, "", "expected a mapping with image, resolution and origin")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise MapError(src, key, "missing required field")
    res = meta["resolution"]
    if not isinstance(res, (int, float)) or res <= 0:
        raise MapError(src, "resolution", f"must be a positive number of meters per cell, got {res!r}")
    origin = meta["origin"]
    if not (
        isinstance(origin, list) and len(origin) == 3 and all(isinstance(v, (int, float)) for v in origin)
    ):
        raise MapError(src, "origin", f"must be [x, y, yaw], got {origin!r}")
    mode = meta.get("mode", "trinary")
    if mode != "trinary":
        raise MapError(src, "mode", f"only 'trinary' maps are supported, got {mode!r}")
    occ_t = float(meta.get("occupied_thresh", 0.65))
    free_t = float(meta.get("free_thresh", 0.25))
    if not 0.0 <= free_t < occ_t <= 1.0:
        raise MapError(
            src, "free_thresh", f"need 0 <= free_thresh < occupied_thresh <= 1, got {free_t}, {occ_t}"
        )
    image_path = (yaml_path.parent / str(meta["image"])).resolve()
    if not image_path.exists():
        raise MapError(src, "image", f"map image {image_path} does not exist")
    try:
        img = read_pgm(image_path)
    except ValueError as e:
        raise MapError(src, "image", f"cannot read {image_path.name}: {e}") from None
    p = img.astype(np.float32) / 255.0
    if not int(meta.get("negate", 0)):
        p = 1.0 - p
    cells = np.full(img.shape, UNKNOWN, dtype=np.int8)
    cells[p > occ_t] = OCCUPIED
    cells[p < free_t] = FREE
    return OccupancyGrid(
        cells=np.flipud(cells).copy(),
        resolution=float(res),
        origin_x=float(origin[0]),
        origin_y=float(origin[1]),
        source=src,
    )


def save_map(grid: OccupancyGrid, yaml_path: str | Path, image_name: str | None = None) -> None:
    """Write ``grid`` as a map_server YAML + PGM pair (free=254, occupied=0, unknown=205)."""
    yaml_path = Path(yaml_path)
    image_name = image_name or yaml_path.with_suffix(".pgm").name
    img = np.full(grid.cells.shape, 205, dtype=np.uint8)
    img[grid.cells == FREE] = 254
    img[grid.cells == OCCUPIED] = 0
    write_pgm(yaml_path.parent / image_name, np.flipud(img))
    meta = {
        "image": image_name,
        "mode": "trinary",
        "resolution": grid.resolution,
        "origin": [grid.origin_x, grid.origin_y, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.25,
    }
    yaml_path.write_text(yaml.safe_dump(meta, sort_keys=False))
