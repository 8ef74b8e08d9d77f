"""Issue 14's goal-metric target: one robot visiting twelve waypoints through the project's
navigator tree while an obstacle closes aisle 1 half-way reaches at least 90 % of them with
at most 2 recoveries each (``bench/blocked_aisle.py``, which prints the per-waypoint table)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_blocked_aisle_reaches_ninety_percent_with_few_recoveries() -> None:
    out = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "blocked_aisle.py")],
        capture_output=True,
        text=True,
        timeout=900,  # about 40 s on a loaded 2-core machine
        check=False,
    )
    m = re.search(r"reached (\d+) of (\d+) waypoints .*, (\d+) with <= 2 recoveries", out.stdout)
    assert m is not None, out.stdout + out.stderr
    reached, total, within = (int(g) for g in m.groups())
    assert total == 12
    assert within / total >= 0.9, out.stdout
    assert out.returncode == 0, out.stdout + out.stderr
    # the waypoint beyond the obstacle is reached by a detour, not through the obstacle
    assert re.search(r"^a1_2\s+SUCCEEDED", out.stdout, re.M), out.stdout
