"""``fleet loadtest``: the load-test report schema, the plots, bad arguments, the SUMO backend."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from fleet.cli.loadtest import loadtest_main
from fleet.loadtest.sampler import LOADTEST_FIELDS, SERIES_FIELDS, STATES
from fleet.runtime.report import REQUIRED_FIELDS, ROBOT_FIELDS

PLOTS = ("throughput.png", "states.png", "congestion.png")
INT_FIELDS = (
    "robots",
    "patrols_assigned",
    "patrols_completed",
    "laps_completed",
    "collisions",
    "deadlocks",
    "reassignments",
)


def _run(tmp_path: Path, *extra: str) -> tuple[int, dict[str, Any]]:
    code = loadtest_main(["--out", str(tmp_path / "out"), "--plot-dir", str(tmp_path / "plots"), *extra])
    report = tmp_path / "out" / "report.json"
    return code, json.loads(report.read_text()) if report.exists() else {}


def _check_schema(d: dict[str, Any], robots: int, duration: float, backend: str) -> None:
    for f in REQUIRED_FIELDS:
        assert f in d, f
    for f in INT_FIELDS:
        assert isinstance(d[f], int) and not isinstance(d[f], bool) and d[f] >= 0, f
    assert d["robots"] == robots
    assert isinstance(d["sim_time_s"], float) and d["sim_time_s"] == pytest.approx(duration, abs=0.5)
    assert isinstance(d["wall_time_s"], float) and d["wall_time_s"] > 0
    assert d["patrols_completed"] <= d["patrols_assigned"]
    assert isinstance(d["per_robot"], list) and len(d["per_robot"]) == robots
    for r in d["per_robot"]:
        for f in ROBOT_FIELDS:
            assert f in r, f
        assert isinstance(r["laps"], int) and isinstance(r["distance_m"], float)

    lt = d["loadtest"]
    for f in LOADTEST_FIELDS:
        assert f in lt, f
    assert lt["backend"] == backend
    for f in ("tick_hz", "status_hz", "step_s", "sample_s", "real_time_factor", "setup_wall_s"):
        assert isinstance(lt[f], float) and lt[f] > 0 or f == "setup_wall_s", f
    assert isinstance(lt["throughput_laps_per_robot_hour"], float)
    assert lt["throughput_laps_per_robot_hour"] == pytest.approx(
        d["laps_completed"] / (robots * d["sim_time_s"] / 3600.0), rel=1e-3
    )
    assert lt["mean_wait_s"] is None or isinstance(lt["mean_wait_s"], float)
    assert isinstance(lt["patrol_routes"], int) and isinstance(lt["route_copies"], int)

    s = lt["series"]
    for f in SERIES_FIELDS:
        assert f in s, f
    n = len(s["t_s"])
    # one sample every sample_s from t=0, plus the final state
    assert n >= math.floor(duration / lt["sample_s"]) + 1
    for f in SERIES_FIELDS:
        if f != "states":
            assert len(s[f]) == n, f
    assert s["t_s"] == sorted(s["t_s"]) and s["t_s"][0] == 0.0
    assert s["t_s"][-1] == pytest.approx(d["sim_time_s"], abs=1e-3)
    assert s["laps"] == sorted(s["laps"]) and s["laps"][-1] == d["laps_completed"]
    assert s["collisions"][-1] == d["collisions"] and s["deadlocks"][-1] == d["deadlocks"]
    assert set(s["states"]) == set(STATES)
    for k in range(n):
        assert sum(s["states"][st][k] for st in STATES) == robots
        assert 0 <= s["waiting"][k] <= robots

    c = lt["congestion"]
    assert c["bin_m"] > 0 and len(c["extent"]) == 4 and len(c["shape"]) == 2
    assert isinstance(c["waiting_robot_samples"], int)
    for x, y, count in c["hotspots"]:
        assert c["extent"][0] <= x <= c["extent"][1] and c["extent"][2] <= y <= c["extent"][3] and count > 0


def test_loadtest_report_schema_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, d = _run(tmp_path, "--robots", "20", "--duration", "60", "--speed", "0")
    assert code == 0
    out = capsys.readouterr().out
    assert "fleet loadtest: 20 robots" in out and "report:" in out
    _check_schema(d, 20, 60.0, "sim")
    lt = d["loadtest"]
    assert lt["tick_hz"] == 2.0 and lt["status_hz"] == 1.0  # the load-test defaults
    assert d["patrols_assigned"] >= 5  # the generated 20-robot warehouse has 5 routes
    for name in PLOTS:
        p = tmp_path / "plots" / name
        assert p.is_file() and p.stat().st_size > 5000, name
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert lt["plots"][name.removesuffix(".png")] == str(p)
    assert (tmp_path / "out" / "loadtest_20.yaml").is_file()  # the generated warehouse


def test_loadtest_rates_are_flags(tmp_path: Path) -> None:
    code, d = _run(
        tmp_path,
        "--robots",
        "4",
        "--duration",
        "10",
        "--tick-hz",
        "10",
        "--status-hz",
        "5",
        "--sample-s",
        "2",
        "--route-copies",
        "1",
    )
    assert code == 0
    lt = d["loadtest"]
    assert lt["tick_hz"] == 10.0 and lt["status_hz"] == 5.0 and lt["sample_s"] == 2.0
    assert lt["route_copies"] == 1 and len(lt["series"]["t_s"]) >= 6


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--robots", "0", "--duration", "10"], "argument --robots/-n: must be at least 1"),
        (["--robots", "x", "--duration", "10"], "argument --robots/-n: expected a whole number"),
        (["--robots", "5", "--duration", "-1"], "argument --duration/-d: must be a positive number"),
        (["--duration", "10"], "the following arguments are required: --robots"),
        (
            ["--robots", "5", "--duration", "10", "--tick-hz", "0"],
            "argument --tick-hz: must be a positive number",
        ),
    ],
)
def test_bad_arguments_exit_2_with_a_clear_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], needle: str
) -> None:
    code, d = _run(tmp_path, *args)
    assert code == 2 and d == {}
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


def test_unknown_backend_and_too_fast_tick(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _ = _run(tmp_path, "--robots", "2", "--duration", "5", "--backend", "nope")
    assert code == 2 and "unknown backend 'nope'" in capsys.readouterr().err
    code, _ = _run(tmp_path, "--robots", "2", "--duration", "5", "--tick-hz", "100")
    assert code == 2 and "--tick-hz: tick period" in capsys.readouterr().err


@pytest.mark.sumo
def test_loadtest_sumo_backend(tmp_path: Path) -> None:
    pytest.importorskip("libsumo")
    pytest.importorskip("sumo")
    code, d = _run(tmp_path, "--robots", "10", "--duration", "60", "--backend", "sumo")
    assert code == 0
    _check_schema(d, 10, 60.0, "sumo")
    assert d["patrols_assigned"] >= 1
    for name in PLOTS:
        assert (tmp_path / "plots" / name).stat().st_size > 5000


def test_fleet_cli_dispatches_loadtest(tmp_path: Path) -> None:
    from fleet.cli.main import main

    out = tmp_path / "cli"
    assert main(["loadtest", "--robots", "3", "--duration", "10", "--out", str(out)]) == 0
    d = json.loads((out / "report.json").read_text())
    assert d["robots"] == 3 and "loadtest" in d and (out / "congestion.png").is_file()
    assert d["loadtest"]["traffic"] is True  # traffic management is on by default
    off = tmp_path / "off"
    assert main(["loadtest", "--robots", "3", "--duration", "10", "--no-traffic", "--out", str(off)]) == 0
    assert json.loads((off / "report.json").read_text())["loadtest"]["traffic"] is False


def test_status_hz_is_the_configs_bus_rate_honoured_by_the_agents(tmp_path: Path) -> None:
    """``--status-hz`` sets the generated config's ``bus.status_hz``; the agents publish at that
    rate (simulated time), whatever the tick rate (``status_max_period_s=None``: every period,
    changed or not; the load test's default publishes on change)."""
    from ports import free_endpoint

    from fleet.loadtest.run import prepare_config
    from fleet.runtime.runner import FleetRunner
    from fleet.viz.display import NullDisplay

    cfg = prepare_config(
        4, tmp_path / "w", tick_hz=4.0, status_hz=1.0, route_copies=1, status_max_period_s=None
    )
    assert cfg.status_hz == 1.0 and cfg.tick_hz == 4.0
    runner = FleetRunner(cfg, duration=10.0, speed=0, endpoint=free_endpoint(), display=NullDisplay())
    runner.run()
    assert [a.ticks for a in runner.agents] == [40] * 4
    assert [a.published for a in runner.agents] == [10] * 4


@pytest.mark.parametrize("n", [4, 20, 100])
def test_every_robot_of_a_load_test_has_a_patrol_loop_with_room(tmp_path: Path, n: int) -> None:
    """The generated floor holds the whole fleet on patrol loops: one route per robot, and no
    loop carries more than one robot per ``PATROL_SPACING_M`` of its length."""
    from collections import Counter

    from fleet.loadtest.run import PATROL_SPACING_M, loop_length, prepare_config

    cfg = prepare_config(n, tmp_path / "w")
    assert len(cfg.robots) == n and len(cfg.routes) >= n
    per_loop = Counter(r.name.split("_c")[0] for r in cfg.routes)
    for r in cfg.routes:
        if "_c" not in r.name:
            assert per_loop[r.name] * PATROL_SPACING_M <= max(loop_length(cfg, r), PATROL_SPACING_M)
