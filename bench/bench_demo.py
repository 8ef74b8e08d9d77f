"""Benchmark of the shipped demos: wall time and simulated time of ``fleet run`` at ``--speed 0``.

Runs each config as a user would (``fleet run CONFIG --speed 0 --duration S --report ...``,
in a subprocess on its own loopback port) and prints one row per config: robots, simulated
seconds, wall seconds, real-time factor, patrols assigned/completed, laps, collisions,
deadlocks, reassignments, and with traffic management the mean wait for right of way. Each
config runs twice, without and with ``--traffic``, so the two can be compared in one run
(``deadlocks`` means different things in the two modes: see ``fleet/runtime/report.py``).

With ``--speed X`` the runs are paced at X times real time instead: the ``x real`` column
then shows how closely the real-time pacer (``fleet.clock.Pacer``) keeps that speed (the
wall time includes the run's setup, a second or two).

    python bench/bench_demo.py                       # 6- and 30-robot demos, 600 s each
    python bench/bench_demo.py --duration 300 --configs configs/warehouse_patrol.yaml
    python bench/bench_demo.py --traffic-only
    python bench/bench_demo.py --speed 20 --duration 120 --configs configs/warehouse_patrol.yaml
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CONFIGS = ("configs/warehouse_patrol.yaml", "configs/warehouse_patrol_30.yaml")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_demo(config: str, duration: float, traffic: bool = False, speed: float = 0.0) -> dict[str, Any]:
    """Run one demo at ``--speed speed`` and return its report (raises on a failed run)."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        cmd = [
            sys.executable, "-m", "fleet.cli", "run", config,
            "--speed", str(speed), "--duration", str(duration), "--no-live",
            "--endpoint", f"tcp/127.0.0.1:{_free_port()}", "--report", str(report),
            "--traffic" if traffic else "--no-traffic",
        ]  # fmt: skip
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
        return dict(json.loads(report.read_text()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS), help="configs to run")
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds per run (default 600)")
    ap.add_argument("--traffic-only", action="store_true", help="only the runs with traffic management")
    ap.add_argument(
        "--speed", type=float, default=0.0, help="multiple of real time (default 0: as fast as possible)"
    )
    args = ap.parse_args(argv)
    head = (
        f"{'config':<30} {'traffic':>7} {'robots':>6} {'sim s':>6} {'wall s':>7} {'x real':>7} "
        f"{'patrols':>8} {'laps':>5} {'coll':>5} {'dead':>5} {'reassign':>8} {'wait s':>7}"
    )
    print(head)
    print("-" * len(head))
    for config in args.configs:
        for traffic in (True,) if args.traffic_only else (False, True):
            r = run_demo(config, args.duration, traffic, args.speed)
            factor = r["sim_time_s"] / r["wall_time_s"] if r["wall_time_s"] > 0 else float("inf")
            patrols = f"{r['patrols_completed']}/{r['patrols_assigned']}"
            wait = f"{r['mean_wait_s']:.1f}" if r.get("mean_wait_s") is not None else "-"
            print(
                f"{Path(config).name:<30} {'on' if traffic else 'off':>7} {r['robots']:>6} "
                f"{r['sim_time_s']:>6.0f} {r['wall_time_s']:>7.1f} {factor:>7.1f} {patrols:>8} "
                f"{r['laps_completed']:>5} {r['collisions']:>5} {r['deadlocks']:>5} {r['reassignments']:>8} {wait:>7}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
