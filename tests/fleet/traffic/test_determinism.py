"""Fleet decisions do not depend on Python's string hashing: two runs of the same config with
different ``PYTHONHASHSEED`` give the same report (wall time aside). Real subprocesses, the
real simulator, real Zenoh on loopback."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from ports import free_endpoint

ROOT = Path(__file__).resolve().parents[3]
PATROL_30 = ROOT / "configs" / "warehouse_patrol_30.yaml"


def _run(tmp_path: Path, hashseed: str) -> dict[str, Any]:
    report = tmp_path / f"r{hashseed}.json"
    env = dict(os.environ, PYTHONHASHSEED=hashseed, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "fleet.cli", "run", str(PATROL_30), "--speed", "0", "--no-live"]
    cmd += ["--duration", "120", "--endpoint", free_endpoint(), "--report", str(report)]
    subprocess.run(cmd, env=env, cwd=ROOT, check=True, timeout=900, capture_output=True)
    d = dict(json.loads(report.read_text()))
    d.pop("wall_time_s")
    d["tasks"].pop("state_dir")  # each run keeps its task book in a directory of its own
    return d


def test_two_runs_with_different_hash_seeds_give_the_same_report(tmp_path: Path) -> None:
    a, b = _run(tmp_path, "1"), _run(tmp_path, "4242")
    assert a["laps_completed"] > 0 and a["traffic"] is not None
    assert a == b
