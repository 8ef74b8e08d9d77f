"""The scripted chaos run, briefly: ``fleet chaos`` on a split fleet of four robots (real
``fleet sim``, ``fleet coordinator`` and ``fleet agent`` processes on loopback), and on one
``fleet run`` process, with a random process killed (``kill -9``) and restarted every few wall
seconds. No task is lost or done twice, nothing collides, no process prints a traceback, every
killed process comes back. ``scale`` marker (``make test-scale``): the long run's figures are in
``docs/faults.md``."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
PATROL = ROOT / "configs" / "warehouse_patrol.yaml"


def chaos(tmp_path: Path, *args: str) -> str:
    """``fleet chaos`` on the patrol config; its output, after checking the verdict line and
    that every killed process came back."""
    cmd = [sys.executable, "-m", "fleet.cli", "chaos", str(PATROL), *args, "--out", str(tmp_path)]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=1100)
    out = p.stdout + p.stderr
    assert "tasks lost: 0   tasks done twice: 0   collisions: 0   tracebacks: 0" in out, out
    assert p.returncode == 0, out
    back = re.findall(r"^\s+\d+\s+\S+\s+\d+\s+([\d.]+|-)\s+([\d.]+|-)$", out, re.M)
    assert back and all(b != "-" for b, _ in back), out  # every killed process came back
    return out


@pytest.mark.scale
@pytest.mark.timeout(1200)  # hang guard: about 2 min on an idle 2-core machine
def test_chaos_run_loses_nothing_duplicates_nothing_and_collides_nowhere(tmp_path: Path) -> None:
    out = chaos(tmp_path, "--robots", "4", "--duration", "400", "--speed", "5", "--every", "5", "--seed", "3")
    kills = re.search(r"(\d+) kills \(sim (\d+), coordinator (\d+), agent (\d+)\)", out)
    assert kills is not None, out
    assert int(kills.group(1)) >= 3, out  # the run did kill processes


@pytest.mark.scale
@pytest.mark.timeout(1200)
def test_a_killed_fleet_run_resumes_its_task_book(tmp_path: Path) -> None:
    """``fleet run --state`` killed and started again: its durable task book brings every task
    back, none is done twice, and its simulator's snapshot its robots (docs/faults.md)."""
    out = chaos(
        tmp_path,
        "--mode",
        "run",
        "--robots",
        "3",
        "--duration",
        "300",
        "--speed",
        "5",
        "--every",
        "12",
        "--seed",
        "2",
    )
    kills = re.search(r"(\d+) kills \(run (\d+)\)", out)
    assert kills is not None and int(kills.group(1)) >= 2, out
