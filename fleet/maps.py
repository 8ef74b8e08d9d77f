"""Occupancy grids, and map files in the Nav2 ``map_server`` format: a YAML file plus an image.

The image is read with Pillow, so every format Pillow reads (PGM, PNG, BMP, JPEG, TIFF, ...)
works, as it does for map_server (GraphicsMagick). The YAML keys are map_server's:

- ``image``: the image path, relative to the YAML file unless absolute;
- ``resolution``: meters per cell;
- ``origin``: ``[x, y, yaw]`` of the lower-left pixel in the ``map`` frame (m, m, rad). The
  grid is axis-aligned: a yaw other than 0 is ignored (with a warning), as most of Nav2 does;
- ``mode``: ``trinary`` (default), ``scale`` or ``raw``;
- ``negate``: 0 (default) or 1;
- ``occupied_thresh`` (default 0.65) and ``free_thresh`` (default 0.25), in [0, 1].

Pixels become cells as map_server makes them: a pixel's shade is the mean of its color
channels scaled to [0, 1] (in ``trinary`` mode an alpha channel is averaged in too), and its
occupancy ``occ`` is ``1 - shade`` (``shade`` with ``negate: 1``). ``trinary``: ``occ >
occupied_thresh`` is :data:`OCCUPIED`, ``occ < free_thresh`` :data:`FREE`, anything between
:data:`UNKNOWN`. ``scale``: the same, except that a pixel that is not fully opaque is unknown
and the values between the thresholds are scaled to 0..100. ``raw``: the cell is
``round(shade * 255)`` when that is in 0..100, unknown otherwise (``negate`` does not apply).
Only :data:`FREE` cells are free; unknown and partly occupied cells are not traversable.

Row 0 of the image is the top of the map (largest ``y``); :class:`OccupancyGrid` stores rows
bottom-up so that ``cells[iy, ix]`` is the cell containing world point
``(origin_x + (ix + 0.5) * res, origin_y + (iy + 0.5) * res)``.
"""

from __future__ import annotations

import difflib
import logging
import math
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import numpy.typing as npt
import yaml
from PIL import Image

from fleet.errors import MapError
from fleet.yamlfile import YamlProblem, parse_yaml

logger = logging.getLogger(__name__)

FREE = 0
OCCUPIED = 100
UNKNOWN = -1

#: Gray levels :func:`save_map` writes. map_saver writes unknown cells as 205, which
#: map_server reads back as free under its default thresholds (occupancy 0.196 < 0.25); a
#: mid gray (occupancy 0.498) reads back as unknown.
FREE_PIXEL, OCCUPIED_PIXEL, UNKNOWN_PIXEL = 254, 0, 128

Cells = npt.NDArray[np.int8]

#: The coarsest map accepted (m per cell) and the farthest origin from 0 (m): far beyond any
#: real map, near enough to refuse a typo before it turns into a grid nobody can drive on.
MAX_RESOLUTION = 100.0
MAX_ORIGIN = 1e6


@dataclass
class OccupancyGrid:
    """A 2-D occupancy grid: ``cells[iy, ix]`` is :data:`FREE` (0), :data:`OCCUPIED` (100),
    :data:`UNKNOWN` (-1) or, from a ``scale`` / ``raw`` map, an occupancy in between; rows
    bottom-up. ``resolution`` in m per cell, ``origin_x`` / ``origin_y`` (m, ``map`` frame)
    the lower-left corner; ``source`` names the map file."""

    cells: Cells
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

    def in_bounds(self, x: float, y: float) -> bool:
        """True if ``(x, y)`` (m) lies on the grid."""
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

    def free_at(
        self, xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], radius: float
    ) -> npt.NDArray[np.bool_]:
        """:meth:`is_free` of every point ``(xs[k], ys[k])`` with ``radius > 0``, as one array
        pass (the same cells and the same float expressions, so the same answers): a config's
        roadmap of thousands of edges is checked sample by sample along every edge."""
        res = self.resolution
        r = int(math.ceil(radius / res))
        cx = np.floor((xs - self.origin_x) / res).astype(np.int64)
        cy = np.floor((ys - self.origin_y) / res).astype(np.int64)
        inside = (cx - r >= 0) & (cy - r >= 0) & (cx + r + 1 <= self.width) & (cy + r + 1 <= self.height)
        d = np.arange(-r, r + 1)
        gx = np.clip(cx[:, None, None] + d[None, None, :], 0, self.width - 1)  # [point, row, col]
        gy = np.clip(cy[:, None, None] + d[None, :, None], 0, self.height - 1)
        wx = self.origin_x + (gx + 0.5) * res - xs[:, None, None]
        wy = self.origin_y + (gy + 0.5) * res - ys[:, None, None]
        mask = wx * wx + wy * wy <= (radius + 0.5 * res) ** 2
        blocked = (self.cells[gy, gx] != FREE) & mask
        out: npt.NDArray[np.bool_] = inside & ~blocked.reshape(len(xs), -1).any(axis=1)
        return out


class MapMode(StrEnum):
    """How map_server turns pixels into cells (see the module docstring)."""

    TRINARY = "trinary"
    SCALE = "scale"
    RAW = "raw"


@dataclass(frozen=True)
class MapMetadata:
    """The fields of a map YAML file. ``image`` is absolute; ``origin`` is ``(x, y, yaw)``."""

    image: Path
    resolution: float
    origin: tuple[float, float, float]
    mode: MapMode = MapMode.TRINARY
    negate: bool = False
    occupied_thresh: float = 0.65
    free_thresh: float = 0.25


def _number(v: object) -> float | None:
    """``v`` as a float if it is a finite int or float (not a bool), else ``None``."""
    if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    return None


def _read_yaml(yaml_path: Path) -> dict[object, object]:
    src = str(yaml_path)
    try:
        text = yaml_path.read_text()
    except FileNotFoundError:
        raise MapError(src, "", "map file does not exist") from None
    except UnicodeDecodeError:
        raise MapError(src, "", "not a text file: name the map's YAML file, not its image") from None
    except OSError as e:
        raise MapError(src, "", f"cannot read the map file ({e})") from None
    try:
        meta = parse_yaml(text)
    except YamlProblem as e:
        raise MapError(src, e.field, e.reason) from None
    except yaml.YAMLError as e:
        raise MapError(src, "", f"not valid YAML ({e})") from None
    if not isinstance(meta, dict):
        raise MapError(src, "", "expected a mapping with image, resolution and origin")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise MapError(src, key, "missing required field")
    return meta


def read_map_yaml(yaml_path: str | Path) -> MapMetadata:
    """The metadata of the map YAML file ``yaml_path``.

    Raises :class:`MapError` naming the file and the field for a missing file, bad YAML, a
    missing required field (``image``, ``resolution``, ``origin``) or a value of the wrong
    type or out of range. Does not open the image.
    """
    yaml_path = Path(yaml_path)
    src = str(yaml_path)
    meta = _read_yaml(yaml_path)
    image, res, origin = meta["image"], meta["resolution"], meta["origin"]
    if not isinstance(image, str) or not image:
        raise MapError(src, "image", f"must be the path of an image file, got {image!r}")
    resolution = _number(res)
    if resolution is None or not 0 < resolution <= MAX_RESOLUTION:
        raise MapError(
            src,
            "resolution",
            f"must be a positive number of meters per cell up to {MAX_RESOLUTION:g}, got {res!r}",
        )
    xyz = [_number(v) for v in origin] if isinstance(origin, list) else []
    if len(xyz) != 3 or None in xyz or any(abs(v or 0.0) > MAX_ORIGIN for v in xyz[:2]):
        raise MapError(
            src,
            "origin",
            f"must be [x, y, yaw] of numbers (m, m, rad), x and y within +-{MAX_ORIGIN:g}, got {origin!r}",
        )
    mode = meta.get("mode", MapMode.TRINARY.value)
    if not isinstance(mode, str) or mode not in {m.value for m in MapMode}:
        close = difflib.get_close_matches(str(mode), [m.value for m in MapMode], n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise MapError(src, "mode", f"must be trinary, scale or raw, got {mode!r}{hint}")
    negate = meta.get("negate", 0)
    if not (isinstance(negate, int) and not isinstance(negate, bool) and negate in (0, 1)):
        raise MapError(src, "negate", f"must be 0 or 1, got {negate!r}")
    thresholds = []
    for key, default in (("occupied_thresh", 0.65), ("free_thresh", 0.25)):
        given = meta.get(key, default)
        t = _number(given)
        if t is None or not 0.0 <= t <= 1.0:
            raise MapError(src, key, f"must be a number in [0, 1], got {given!r}")
        thresholds.append(t)
    occ_t, free_t = thresholds
    if not free_t < occ_t:
        raise MapError(
            src, "free_thresh", f"need 0 <= free_thresh < occupied_thresh <= 1, got {free_t}, {occ_t}"
        )
    x, y, yaw = (v for v in xyz if v is not None)
    if yaw != 0.0:
        logger.warning("%s: origin yaw %g rad ignored: the map is used axis-aligned", src, yaw)
    return MapMetadata(
        image=(yaml_path.parent / image).resolve(),
        resolution=resolution,
        origin=(x, y, yaw),
        mode=MapMode(mode),
        negate=bool(negate),
        occupied_thresh=occ_t,
        free_thresh=free_t,
    )


def _shades(img: Image.Image) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64] | None]:
    """The mean color channel of every pixel and its alpha (``None`` without an alpha
    channel), both in [0, 1], rows top-down."""
    if img.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N"):  # 16-bit gray
        return np.clip(np.asarray(img, dtype=np.float64) / 65535.0, 0.0, 1.0), None
    if img.mode == "F":
        raise ValueError("floating-point images are not supported")
    if img.has_transparency_data:
        rgba = np.asarray(img.convert("RGBA"), dtype=np.float64) / 255.0
        return rgba[..., :3].mean(axis=2), rgba[..., 3]
    if img.mode in ("L", "1"):
        return np.asarray(img.convert("L"), dtype=np.float64) / 255.0, None
    return np.asarray(img.convert("RGB"), dtype=np.float64).mean(axis=2) / 255.0, None


def occupancy(img: Image.Image, meta: MapMetadata) -> Cells:
    """The cells of image ``img`` read as ``meta`` says (map_server's rules, see the module
    docstring), rows top-down like the image. Raises ``ValueError`` for an image mode that
    has no gray level (floating point)."""
    color, alpha = _shades(img)
    cells = np.full(color.shape, UNKNOWN, dtype=np.int8)
    if meta.mode is MapMode.RAW:
        value = np.floor(color * 255.0 + 0.5)
        raw = (value >= FREE) & (value <= OCCUPIED)
        cells[raw] = value[raw].astype(np.int8)
        return cells
    shade = color if alpha is None or meta.mode is MapMode.SCALE else (3.0 * color + alpha) / 4.0
    occ = shade if meta.negate else 1.0 - shade
    occupied, free = occ > meta.occupied_thresh, occ < meta.free_thresh
    if meta.mode is MapMode.SCALE:
        between = ~occupied & ~free
        scaled = (occ - meta.free_thresh) / (meta.occupied_thresh - meta.free_thresh) * 100.0
        cells[between] = np.rint(scaled[between]).astype(np.int8)
    cells[occupied] = OCCUPIED
    cells[free] = FREE
    if meta.mode is MapMode.SCALE and alpha is not None:
        cells[alpha < 1.0] = UNKNOWN
    return cells


def load_map(yaml_path: str | Path) -> OccupancyGrid:
    """Load a map_server map: the YAML file ``yaml_path`` and the image it names.

    Raises :class:`MapError` naming the YAML file and the field (``image`` when the image is
    missing, not a file or cannot be read as an image).
    """
    meta = read_map_yaml(yaml_path)
    src = str(yaml_path)
    if not meta.image.exists():
        raise MapError(src, "image", f"map image {meta.image} does not exist")
    if not meta.image.is_file():
        raise MapError(src, "image", f"map image {meta.image} is not a file")
    try:
        with Image.open(meta.image) as img:
            cells = occupancy(img, meta)
    except (OSError, ValueError, Image.DecompressionBombError) as e:
        raise MapError(src, "image", f"cannot read {meta.image.name}: {e}") from None
    return OccupancyGrid(
        cells=np.flipud(cells).copy(),
        resolution=meta.resolution,
        origin_x=meta.origin[0],
        origin_y=meta.origin[1],
        source=src,
    )


def save_map(grid: OccupancyGrid, yaml_path: str | Path, image_name: str | None = None) -> None:
    """Write ``grid`` as a map_server YAML + PGM pair (``image_name``, default the YAML's stem
    ``.pgm``, next to it) in ``trinary`` mode with thresholds 0.65 / 0.25 and origin yaw 0.

    As map_saver does, cells up to 25 are written free (254) and cells from 65 occupied (0);
    the others and unknown cells are written as :data:`UNKNOWN_PIXEL`, so that :func:`load_map`
    reads them back as unknown."""
    yaml_path = Path(yaml_path)
    image_name = image_name or yaml_path.with_suffix(".pgm").name
    img = np.full(grid.cells.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    known = (grid.cells >= FREE) & (grid.cells <= OCCUPIED)
    img[known & (grid.cells <= 25)] = FREE_PIXEL
    img[known & (grid.cells >= 65)] = OCCUPIED_PIXEL
    Image.fromarray(np.ascontiguousarray(np.flipud(img))).save(yaml_path.parent / image_name, "PPM")
    meta = {
        "image": image_name,
        "mode": MapMode.TRINARY.value,
        "resolution": grid.resolution,
        "origin": [grid.origin_x, grid.origin_y, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.25,
    }
    yaml_path.write_text(yaml.safe_dump(meta, sort_keys=False))
