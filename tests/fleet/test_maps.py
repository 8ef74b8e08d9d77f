"""Map files as Nav2's map_server reads them: any image format Pillow reads, the trinary,
scale and raw modes, negate and the thresholds; errors name the map file and the field."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from PIL import Image

from fleet.errors import ConfigError, MapError
from fleet.maps import FREE, OCCUPIED, UNKNOWN, OccupancyGrid, load_map, save_map

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SHIPPED_MAP = CONFIGS / "maps" / "warehouse.yaml"


def shipped_pixels() -> np.ndarray:
    with Image.open(SHIPPED_MAP.with_suffix(".pgm")) as img:
        return np.asarray(img.convert("L"))


def write_map(tmp_path: Path, image: Image.Image | np.ndarray, name: str = "m.png", **meta: Any) -> Path:
    """A map YAML in ``tmp_path`` naming ``image`` saved as ``name``; ``meta`` overrides keys."""
    if isinstance(image, np.ndarray):
        image = Image.fromarray(image)
    image.save(tmp_path / name)
    doc = {"image": name, "resolution": 0.1, "origin": [0.0, 0.0, 0.0], **meta}
    path = tmp_path / f"{Path(name).stem}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def cells_of(path: Path) -> np.ndarray:
    """The cells of the map at ``path``, rows top-down like its image."""
    return np.flipud(load_map(path).cells)


def test_the_shipped_pgm_map_has_free_occupied_and_nothing_else() -> None:
    grid = load_map(SHIPPED_MAP)
    assert set(np.unique(grid.cells)) == {FREE, OCCUPIED}
    assert grid.resolution == 0.1 and (grid.origin_x, grid.origin_y) == (0.0, 0.0)
    assert grid.source == str(SHIPPED_MAP)


@pytest.mark.parametrize("fmt", ["png", "bmp", "tiff"])
def test_a_gray_image_in_another_format_loads_like_the_pgm(tmp_path: Path, fmt: str) -> None:
    grid = load_map(write_map(tmp_path, shipped_pixels(), f"w.{fmt}"))
    expected = load_map(SHIPPED_MAP)
    assert np.array_equal(grid.cells, expected.cells)
    assert (grid.resolution, grid.origin_x, grid.origin_y) == (0.1, 0.0, 0.0)


def test_an_rgb_png_uses_the_mean_of_its_channels(tmp_path: Path) -> None:
    px = shipped_pixels()
    rgb = np.stack([px, px, px], axis=2)
    assert np.array_equal(load_map(write_map(tmp_path, rgb)).cells, load_map(SHIPPED_MAP).cells)
    # (255 + 255 + 0) / 3 = 170: occupancy 0.33, between the thresholds: unknown
    colored = np.array([[[255, 255, 0], [255, 255, 255], [0, 0, 0]]], dtype=np.uint8)
    assert cells_of(write_map(tmp_path, colored, "c.png")).tolist() == [[UNKNOWN, FREE, OCCUPIED]]


def test_negate_swaps_black_and_white(tmp_path: Path) -> None:
    inverted = 255 - shipped_pixels()
    grid = load_map(write_map(tmp_path, inverted, negate=1))
    assert np.array_equal(grid.cells, load_map(SHIPPED_MAP).cells)
    assert not np.array_equal(load_map(write_map(tmp_path, inverted, "plain.png")).cells, grid.cells)


def test_the_thresholds_decide(tmp_path: Path) -> None:
    # occupancy (255 - v) / 255: 0 -> 1.0, 60 -> 0.76, 102 -> 0.6, 200 -> 0.22, 255 -> 0.0
    row = np.array([[0, 60, 102, 200, 255]], dtype=np.uint8)
    path = write_map(tmp_path, row, occupied_thresh=0.8, free_thresh=0.2)
    assert cells_of(path).tolist() == [[OCCUPIED, UNKNOWN, UNKNOWN, UNKNOWN, FREE]]
    path = write_map(tmp_path, row, "b.png", occupied_thresh=0.7, free_thresh=0.3)
    assert cells_of(path).tolist() == [[OCCUPIED, OCCUPIED, UNKNOWN, FREE, FREE]]


def test_scale_mode_scales_between_the_thresholds_and_transparent_is_unknown(tmp_path: Path) -> None:
    gray = np.array([0, 40, 100, 150, 210, 255, 128], dtype=np.uint8)
    alpha = np.array([255, 255, 255, 255, 255, 255, 254], dtype=np.uint8)
    rgba = np.stack([gray, gray, gray, alpha], axis=1)[None, :, :]
    path = write_map(tmp_path, rgba, mode="scale", occupied_thresh=0.9, free_thresh=0.1)
    # occupancies 1.0, 0.843, 0.608, 0.412, 0.176, 0.0 -> (occ - 0.1) / 0.8 * 100 in between
    assert cells_of(path).tolist() == [[OCCUPIED, 93, 63, 39, 10, FREE, UNKNOWN]]


def test_raw_mode_keeps_values_up_to_100(tmp_path: Path) -> None:
    row = np.array([[0, 1, 50, 100, 101, 255]], dtype=np.uint8)
    assert cells_of(write_map(tmp_path, row, mode="raw")).tolist() == [[0, 1, 50, 100, UNKNOWN, UNKNOWN]]
    # negate does not apply to raw values
    assert cells_of(write_map(tmp_path, row, "n.png", mode="raw", negate=1)).tolist() == [
        [0, 1, 50, 100, UNKNOWN, UNKNOWN]
    ]


def test_trinary_mode_averages_an_alpha_channel_in(tmp_path: Path) -> None:
    # opaque 205 gray: (3 * 205 + 255) / 4 = 217.5 -> occupancy 0.15 -> free;
    # transparent white: (3 * 255 + 0) / 4 = 191.25 -> occupancy 0.25 -> unknown
    rgba = np.array([[[205, 205, 205, 255], [255, 255, 255, 0], [0, 0, 0, 255]]], dtype=np.uint8)
    assert cells_of(write_map(tmp_path, rgba)).tolist() == [[FREE, UNKNOWN, OCCUPIED]]


def test_a_sixteen_bit_png_reads_like_the_eight_bit_one(tmp_path: Path) -> None:
    px = shipped_pixels()
    deep = write_map(tmp_path, Image.fromarray(px.astype(np.uint16) * 257), "deep.png")
    assert np.array_equal(load_map(deep).cells, load_map(SHIPPED_MAP).cells)


def test_the_image_path_is_relative_to_the_yaml_unless_absolute(tmp_path: Path) -> None:
    (tmp_path / "img").mkdir()
    Image.fromarray(shipped_pixels()).save(tmp_path / "img" / "w.png")
    rel = tmp_path / "rel.yaml"
    rel.write_text(yaml.safe_dump({"image": "img/w.png", "resolution": 0.1, "origin": [1.0, 2.0, 0.0]}))
    absolute = tmp_path / "abs.yaml"
    absolute.write_text(
        yaml.safe_dump({"image": str(tmp_path / "img" / "w.png"), "resolution": 0.1, "origin": [1, 2, 0]})
    )
    a, b = load_map(rel), load_map(absolute)
    assert np.array_equal(a.cells, b.cells)
    assert (a.origin_x, a.origin_y) == (1.0, 2.0)


def test_an_origin_yaw_is_ignored_with_a_warning(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="fleet.maps"):
        grid = load_map(write_map(tmp_path, shipped_pixels(), origin=[0.5, 0.0, 0.3]))
    assert grid.origin_x == 0.5
    assert "yaw 0.3 rad ignored" in caplog.text


def test_save_map_writes_a_pgm_that_reads_back(tmp_path: Path) -> None:
    grid = load_map(SHIPPED_MAP)
    save_map(grid, tmp_path / "copy.yaml")
    assert (tmp_path / "copy.pgm").read_bytes() == SHIPPED_MAP.with_suffix(".pgm").read_bytes()
    assert np.array_equal(load_map(tmp_path / "copy.yaml").cells, grid.cells)


def test_save_map_keeps_unknown_cells_unknown(tmp_path: Path) -> None:
    cells = np.array([[UNKNOWN, 0, 25, 26, 64, 65, 100]], dtype=np.int8)
    save_map(OccupancyGrid(cells=cells, resolution=0.5, origin_x=-1.0, origin_y=0.0), tmp_path / "s.yaml")
    with Image.open(tmp_path / "s.pgm") as img:
        assert np.asarray(img).tolist() == [[128, 254, 254, 128, 128, 0, 0]]
    back = load_map(tmp_path / "s.yaml")
    assert back.cells.tolist() == [[UNKNOWN, FREE, FREE, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED]]
    assert (back.resolution, back.origin_x) == (0.5, -1.0)


# ----------------------------------------------------------------------------- bad maps

GOOD: dict[str, Any] = {"image": "m.png", "resolution": 0.1, "origin": [0.0, 0.0, 0.0]}


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"image": None}, "image", "path of an image file"),
        ({"resolution": 0}, "resolution", "positive number of meters per cell"),
        ({"resolution": float("nan")}, "resolution", "positive number"),
        ({"resolution": True}, "resolution", "positive number"),
        ({"origin": [0.0, 0.0]}, "origin", "[x, y, yaw]"),
        ({"origin": [0.0, float("nan"), 0.0]}, "origin", "[x, y, yaw]"),
        ({"mode": "trinery"}, "mode", "did you mean 'trinary'?"),
        ({"mode": ["raw"]}, "mode", "trinary, scale or raw"),
        ({"negate": 0.5}, "negate", "0 or 1"),
        ({"negate": "yes"}, "negate", "0 or 1"),
        ({"occupied_thresh": "high"}, "occupied_thresh", "in [0, 1], got 'high'"),
        ({"free_thresh": 1.5}, "free_thresh", "in [0, 1]"),
        ({"free_thresh": 0.7}, "free_thresh", "free_thresh < occupied_thresh"),
        ({"image": "none.png"}, "image", "does not exist"),
        ({"image": "."}, "image", "not a file"),
        ({"image": "m.yaml"}, "image", "cannot read m.yaml"),
    ],
)
def test_a_bad_map_yaml_names_the_file_and_the_field(
    tmp_path: Path, change: dict[str, Any], field: str, words: str
) -> None:
    Image.fromarray(np.zeros((2, 2), dtype=np.uint8)).save(tmp_path / "m.png")
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({**GOOD, **change}))
    with pytest.raises(MapError) as ei:
        load_map(path)
    assert isinstance(ei.value, ConfigError)
    assert str(ei.value).startswith(f"{path}: {field}: "), str(ei.value)
    assert words in ei.value.reason


@pytest.mark.parametrize("missing", ["image", "resolution", "origin"])
def test_a_required_field_is_missing(tmp_path: Path, missing: str) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({k: v for k, v in GOOD.items() if k != missing}))
    with pytest.raises(MapError, match=f"m.yaml: {missing}: missing required field"):
        load_map(path)


def test_the_image_given_instead_of_the_yaml(tmp_path: Path) -> None:
    shutil.copy(SHIPPED_MAP.with_suffix(".pgm"), tmp_path / "w.pgm")
    with pytest.raises(MapError) as ei:
        load_map(tmp_path / "w.pgm")
    assert str(ei.value).startswith(f"{tmp_path / 'w.pgm'}: ")


@pytest.mark.parametrize(
    ("text", "words"),
    [("image: [", "not valid YAML"), ("- a\n- b\n", "expected a mapping"), (None, "does not exist")],
)
def test_a_map_file_that_is_not_a_map_yaml(tmp_path: Path, text: str | None, words: str) -> None:
    path = tmp_path / "m.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(MapError, match=words):
        load_map(path)
