"""Fleet outcomes over long runs with traffic management on (the default): nobody runs flat,
nobody collides, and on the shipped configs traffic management pays for itself.

Long runs (simulated hours, hundreds of robots) carry the ``scale`` marker
(``make test-scale``). Real simulator, real Zenoh on loopback, real py_trees."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint

from fleet.cli.main import main
from fleet.loadtest.run import run_loadtest

ROOT = Path(__file__).resolve().parents[3]

#: Laps with traffic management / laps without over 1800 simulated seconds, measured on the
#: shipped configs: 150 / 158 = 0.95 with 6 robots (147 before the roadmap was cut into cells,
#: ``traffic.cell_m``; 143 / 155 earlier still), 188 / 184 = 1.02 with 30 (187 before cells). The tests hold these margins (runs are
#: deterministic); the issue's target of 1.0 at 6 robots is not met: the last case expects
#: that failure until it is.
MIN_RATIO = {"configs/warehouse_patrol.yaml": 0.93, "configs/warehouse_patrol_30.yaml": 1.0}
TARGET = 1.0


def _run(tmp_path: Path, config: str, duration: float, *flags: str) -> dict[str, Any]:
    report = tmp_path / f"r{len(list(tmp_path.iterdir()))}.json"
    args = ["run", str(ROOT / config), "--speed", "0", "--no-live", "--duration", str(duration)]
    assert main([*args, "--endpoint", free_endpoint(), "--report", str(report), *flags]) == 0
    return dict(json.loads(report.read_text()))


@pytest.mark.scale
@pytest.mark.timeout(3600)
@pytest.mark.parametrize(
    ("config", "min_ratio"),
    [
        ("configs/warehouse_patrol.yaml", MIN_RATIO["configs/warehouse_patrol.yaml"]),
        ("configs/warehouse_patrol_30.yaml", MIN_RATIO["configs/warehouse_patrol_30.yaml"]),
        pytest.param(
            "configs/warehouse_patrol.yaml",
            TARGET,
            marks=pytest.mark.xfail(
                strict=True,
                reason="issue 13's target is not met with 6 robots: 150 laps with traffic management "
                "against 158 without (0.95; docs/performance.md, Following closely: roadmap cells)",
            ),
            id="6-robots-target",
        ),
    ],
)
def test_traffic_management_keeps_the_laps_of_the_shipped_configs(
    tmp_path: Path, config: str, min_ratio: float
) -> None:
    on = _run(tmp_path, config, 1800.0)
    off = _run(tmp_path, config, 1800.0, "--no-traffic")
    assert on["collisions"] == 0 and on["deadlocks"] == 0
    ratio = on["laps_completed"] / max(1, off["laps_completed"])
    assert ratio >= min_ratio, (on["laps_completed"], off["laps_completed"])
    assert on["min_battery"] > 0.05 and on["p95_wait_s"] is not None


#: Picks done with traffic management / without in 600 simulated seconds on the shipped
#: picking config: 24 / 23 (1.04; every one of its 24 picks done; 22 before task legs drove
#: with the flow, 11 before a task ending where the robot stood kept its first stops). The
#: issue's target, 1.0, is met and held.
PICK_RATIO = 1.0


@pytest.mark.scale
@pytest.mark.timeout(1800)
def test_picks_under_traffic_management_keep_up_with_picks_without(tmp_path: Path) -> None:
    args = ("--tree", "picking")
    on = _run(tmp_path, "configs/warehouse_picking.yaml", 600.0, *args)
    off = _run(tmp_path, "configs/warehouse_picking.yaml", 600.0, *args, "--no-traffic")
    assert on["collisions"] == 0 and on["deadlocks"] == 0
    ratio = on["picks_completed"] / max(1, off["picks_completed"])
    assert ratio >= PICK_RATIO, (on["picks_completed"], off["picks_completed"])


@pytest.mark.scale
@pytest.mark.timeout(3600)
@pytest.mark.xfail(
    strict=True,
    reason="not met: in the load test every robot patrols, and with traffic management the "
    "charging trips and the charger queues of the 100-robot floor collapse the fleet after "
    "minute 30 (with roadmap cells: 39 of 100 below 5 % in 3600 s, 7 deadlock episodes, 1325 "
    "laps; 91 below 5 % before cells; docs/performance.md, Following closely: roadmap cells)",
)
def test_no_robot_runs_flat_in_an_hour_with_100_robots(tmp_path: Path) -> None:
    res = run_loadtest(100, 3600.0, out_dir=tmp_path / "lt", endpoint=free_endpoint())
    d = res.data
    lowest = min(r["battery_min"] for r in d["per_robot"])
    assert d["min_battery"] == pytest.approx(lowest)
    assert lowest > 0.05, sorted((r["battery_min"], r["name"]) for r in d["per_robot"])[:5]
    assert d["collisions"] == 0 and d["deadlocks"] == 0
