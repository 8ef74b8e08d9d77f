"""``bench/outcome_table.py``, the fleet-outcome table of docs/performance.md, on a small fleet:
its rows are the figures of the real runs' reports (simulator with and without traffic
management, and SUMO on the same generated warehouse), and it says that the three runs loaded
the same world and gave every robot the same first patrol loop.

Cheap: 2 robots for 90 simulated seconds per run (three ``fleet loadtest`` subprocesses,
seconds each). The long runs of the table itself are measured by hand (docs/performance.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("libsumo")

ROOT = Path(__file__).resolve().parents[3]
DURATION = 90.0
ROBOTS = 2


def _rows(stdout: str) -> tuple[list[str], list[list[str]]]:
    table = [line for line in stdout.splitlines() if line.startswith("|")]
    cells = [[c.strip() for c in line.strip().strip("|").split("|")] for line in table]
    assert set(cells[1]) == {"---"}, table[1]
    return cells[0], cells[2:]


def test_outcome_table_rows_are_the_run_reports(tmp_path: Path) -> None:
    keep = tmp_path / "runs"
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "bench" / "outcome_table.py"),
            "--sizes",
            str(ROBOTS),
            "--duration",
            f"{DURATION:g}",
            "--keep",
            str(keep),
            "--json",
            str(tmp_path / "rows.json"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,  # three runs of seconds each; generous for a loaded 2-core machine
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    head, rows = _rows(proc.stdout)
    assert head[:4] == ["robots", "simulated s", "backend", "traffic"]
    assert [(r[2], r[3]) for r in rows] == [("sim", "on"), ("sim", "off"), ("sumo", "off")]
    for r, label in zip(rows, ["sim-on", "sim-off", "sumo-off"], strict=True):
        cell = dict(zip(head, r, strict=True))
        rep = json.loads((keep / f"{ROBOTS}-{label}-{DURATION:g}s.json").read_text())
        assert rep["robots"] == ROBOTS and int(cell["robots"]) == ROBOTS
        assert int(cell["simulated s"]) == round(rep["sim_time_s"]) == DURATION
        assert int(cell["laps"]) == rep["laps_completed"] > 0  # robots lapped in 90 s
        per_h = rep["laps_completed"] / (ROBOTS * rep["sim_time_s"] / 3600.0)
        assert float(cell["laps/robot-h"]) == pytest.approx(per_h, abs=0.006)
        assert float(cell["laps/robot-h"]) == pytest.approx(rep["throughput_laps_per_robot_hour"], abs=0.006)
        assert float(cell["min battery"].rstrip("%")) == pytest.approx(100 * rep["min_battery"], abs=0.06)
        assert 0.0 < rep["min_battery"] < 1.0
        flat = sum(1 for p in rep["per_robot"] if p["battery_min"] < 0.05)
        assert int(cell["below 5 %"]) == flat
        assert float(cell["idle"].rstrip("%")) == pytest.approx(100 * rep["idle_fraction"], abs=0.6)
        assert int(cell["collisions"]) == rep["collisions"]
        assert float(cell["stopped s"]) == pytest.approx(rep["loadtest"]["mean_wait_s"], abs=0.6)
        assert float(cell["wall s"]) > 0
        if label == "sim-on":  # right-of-way waits exist only with traffic management
            assert float(cell["mean wait s"]) == pytest.approx(rep["mean_wait_s"], abs=0.6)
            assert float(cell["p95 wait s"]) == pytest.approx(rep["p95_wait_s"], abs=0.6)
        else:
            assert cell["mean wait s"] == cell["p95 wait s"] == "–"
        if label == "sumo-off":  # SUMO's deadlocks are its teleports
            assert rep["backend"] == "sumo" and rep["teleports"] is not None
            assert cell["deadlocks"] == f"{rep['teleports']} teleports"
        else:
            assert int(cell["deadlocks"]) == rep["deadlocks"]
    # the comparison is fair: the three runs loaded one world and began with the same patrols
    same = [line for line in proc.stdout.splitlines() if line.startswith(f"# {ROBOTS} robots:")]
    assert len(same) == 1 and "all 3 runs loaded the same world" in same[0], proc.stdout
    assert f"{ROBOTS} of {ROBOTS} robots were given the same first loop in every run" in same[0]
    figures = json.loads((tmp_path / "rows.json").read_text())
    assert [f["laps"] for f in figures] == [int(r[4]) for r in rows]
