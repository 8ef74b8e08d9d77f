"""The warehouse generator: deterministic, collision-free, scales with the fleet, and the
shipped configs are exactly its output."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.errors import ConfigError
from fleet.warehouse import generate_warehouse, main

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def assert_collision_free(cfg: FleetConfig) -> None:
    """Every roadmap edge, start, parking spot, charger and station clears the robot radius."""
    grid, r = cfg.grid, cfg.sim.model.radius
    for a, b in cfg.roadmap.edges:
        (ax, ay), (bx, by) = cfg.roadmap.pos(a), cfg.roadmap.pos(b)
        n = max(1, math.ceil(math.hypot(bx - ax, by - ay) / (grid.resolution / 2)))
        for k in range(n + 1):
            x, y = ax + (bx - ax) * k / n, ay + (by - ay) * k / n
            assert grid.is_free(x, y, r), f"edge {a}-{b} blocked at ({x:.2f}, {y:.2f})"
    poses = [s.start for s in cfg.robots] + cfg.parking + [c.pose for c in cfg.chargers]
    poses += [s.pose for s in cfg.stations.values()]
    for p in poses:
        assert grid.is_free(p.x, p.y, r), p


def test_generator_is_deterministic(tmp_path: Path) -> None:
    a = generate_warehouse(tmp_path / "a", "w", 12, seed=7)
    b = generate_warehouse(tmp_path / "b", "w", 12, seed=7)
    assert a.read_bytes() == b.read_bytes()
    for f in ("w.yaml", "w.pgm"):
        assert (tmp_path / "a" / "maps" / f).read_bytes() == (tmp_path / "b" / "maps" / f).read_bytes()
    c = generate_warehouse(tmp_path / "c", "w", 12, seed=8)
    assert c.read_bytes() != a.read_bytes()  # the seed picks different task shelves


def test_shipped_configs_are_the_generator_output(tmp_path: Path) -> None:
    assert main(["--shipped", "--out", str(tmp_path)]) == 0
    for name in ("warehouse_patrol.yaml", "warehouse_patrol_30.yaml", "warehouse_picking.yaml"):
        assert (tmp_path / name).read_text() == (CONFIGS / name).read_text(), name
    for name in ("warehouse.yaml", "warehouse.pgm"):
        assert (tmp_path / "maps" / name).read_bytes() == (CONFIGS / "maps" / name).read_bytes()


def _seg_dist(p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance (m) from ``p`` to the segment ``a``-``b``."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    t = ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / ((dx * dx + dy * dy) or 1.0)
    t = min(1.0, max(0.0, t))
    return math.dist(p, (a[0] + t * dx, a[1] + t * dy))


def test_default_warehouse_layout(tmp_path: Path) -> None:
    cfg = load_config(generate_warehouse(tmp_path, "small", 6))
    xmin, xmax, ymin, ymax = cfg.grid.extent
    assert (xmax - xmin, ymax - ymin) == (pytest.approx(30.0), pytest.approx(20.0))
    assert cfg.grid.resolution == 0.1
    # Walls all around.
    assert not cfg.grid.is_free(0.05, 10.0) and not cfg.grid.is_free(29.95, 10.0)
    assert not cfg.grid.is_free(15.0, 0.05) and not cfg.grid.is_free(15.0, 19.95)
    # chargers beside the corridors, each with its own way in: 1 m off the nearest roadmap
    # edge, at least 1 m from each other and from the parking spots
    assert len(cfg.chargers) >= 2
    segs = [(cfg.roadmap.pos(a), cfg.roadmap.pos(b)) for a, b in cfg.roadmap.edges]
    for c in cfg.chargers:
        assert min(_seg_dist((c.pose.x, c.pose.y), a, b) for a, b in segs) == pytest.approx(1.0)
        others = [o.pose for o in cfg.chargers if o is not c] + list(cfg.parking)
        assert min(math.hypot(c.pose.x - o.x, c.pose.y - o.y) for o in others) >= 1.0 - 1e-9
    assert len(cfg.routes) >= 3
    assert len(cfg.robots) == 6
    assert_collision_free(cfg)


def test_two_robots_can_pass_in_every_aisle(tmp_path: Path) -> None:
    cfg = load_config(generate_warehouse(tmp_path, "small", 6))
    r = cfg.sim.model.radius
    aisle_edges = [(a, b) for a, b in cfg.roadmap.edges if a[0] == "a" and a.split("_")[0] == b.split("_")[0]]
    assert aisle_edges
    for a, b in aisle_edges:
        (x, ya), (_, yb) = cfg.roadmap.pos(a), cfg.roadmap.pos(b)
        for y in (ya, (ya + yb) / 2, yb):
            # side by side, 0.1 m apart
            assert cfg.grid.is_free(x - r - 0.05, y, r) and cfg.grid.is_free(x + r + 0.05, y, r)


def test_patrol_routes_go_up_one_aisle_and_down_the_next(tmp_path: Path) -> None:
    cfg = load_config(generate_warehouse(tmp_path, "small", 6))
    route = cfg.route("aisles_3_4")
    lap = cfg.route_poses(route)
    ys = [p.y for p in lap]
    xs = sorted({p.x for p in lap})
    assert len(xs) == 2 and xs[1] - xs[0] == pytest.approx(3.0)
    assert max(ys) - min(ys) > 10.0
    up = [p for p in lap if p.x == xs[0]]
    assert [p.y for p in up] == sorted(p.y for p in up)  # aisle 3 driven north
    assert all(abs(p.theta - math.pi / 2) < 1e-9 for p in up[:-1])


def test_thirty_robots_share_the_small_map(tmp_path: Path) -> None:
    generate_warehouse(tmp_path, "six", 6, map_name="wh")
    before = (tmp_path / "maps" / "wh.pgm").read_bytes()
    cfg = load_config(generate_warehouse(tmp_path, "thirty", 30, map_name="wh"))
    assert (tmp_path / "maps" / "wh.pgm").read_bytes() == before
    assert len(cfg.robots) == 30
    assert_collision_free(cfg)


def test_too_small_warehouse_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as ei:
        generate_warehouse(tmp_path, "w", 200, aisles=2, parking_rows=1)
    msg = str(ei.value)
    assert "n_robots" in msg and "200 robots do not fit" in msg and "parking spots" in msg
    with pytest.raises(ConfigError, match="chargers"):
        generate_warehouse(tmp_path, "w", 6, chargers=100)


@pytest.mark.parametrize("n", [100, 1000])
def test_large_warehouses_load_and_validate(tmp_path: Path, n: int) -> None:
    # how long generation takes is measured in bench/bench_setup.py, not asserted here
    path = generate_warehouse(tmp_path, f"w{n}", n)
    cfg = load_config(path)
    assert len(cfg.robots) == n
    small = load_config(CONFIGS / "warehouse_patrol.yaml")
    assert cfg.grid.width * cfg.grid.height > small.grid.width * small.grid.height
    assert len(cfg.routes) > len(small.routes)
    assert cfg.roadmap.is_connected()
    if n == 100:
        assert_collision_free(cfg)


def test_cli_writes_a_loadable_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--robots", "12", "--out", str(tmp_path), "--name", "cli"]) == 0
    assert str(tmp_path / "cli.yaml") in capsys.readouterr().out
    assert len(load_config(tmp_path / "cli.yaml").robots) == 12
    assert main(["--robots", "500", "--aisles", "1", "--parking-rows", "1", "--out", str(tmp_path)]) == 2
    assert "do not fit" in capsys.readouterr().out


def test_chargers_on_both_corridors_when_asked() -> None:
    from fleet.warehouse import chargers_of, plan_layout

    lay = plan_layout(100, 25, 20.0)
    mid = (lay.y_south + lay.y_north) / 2
    one = chargers_of(lay, 100, 50)
    two = chargers_of(lay, 100, 51, sides=2)
    assert all(c["pose"][1] < mid for c in one)  # 50 fit on the south corridor
    south = sum(1 for c in two if c["pose"][1] < mid)
    assert (south, len(two) - south) == (26, 25)
    assert len({tuple(c["pose"][:2]) for c in two}) == 51
