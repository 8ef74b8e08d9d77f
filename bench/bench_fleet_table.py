"""The fleet-outcome table of docs/performance.md: long runs at several fleet sizes, with and
without traffic management, and SUMO on the same network and robot count.

Sizes 6 and 30 run the shipped configs (``fleet run``); larger sizes run ``fleet loadtest``'s
generated warehouse. Every run is a subprocess at ``--speed 0`` on its own loopback port and
prints one Markdown row as soon as it ends: throughput (laps per robot-hour), mean / p95 wait
for right of way, idle fraction, lowest battery seen, collisions, deadlocks (for SUMO runs:
its teleports, the vehicles it moved on after they waited too long).

    python bench/bench_fleet_table.py                              # 6, 30, 100 robots, 1800 s
    python bench/bench_fleet_table.py --sizes 1000 5000 --duration 1800
    python bench/bench_fleet_table.py --sizes 6 --no-sumo --duration 600
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = {6: "configs/warehouse_patrol.yaml", 30: "configs/warehouse_patrol_30.yaml"}
HEAD = (
    "| robots | backend | traffic | laps | laps/robot-h | mean wait s | p95 wait s | idle | "
    "min battery | collisions | deadlocks | wall s |"
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def command(n: int, duration: float, backend: str, traffic: bool) -> list[str]:
    """The ``fleet`` arguments of one run (report and endpoint options are added later)."""
    flag = "--traffic" if traffic else "--no-traffic"
    if n in SHIPPED:
        return ["run", SHIPPED[n], "--backend", backend, "--duration", f"{duration:g}", flag]
    return ["loadtest", "--robots", str(n), "--backend", backend, "--duration", f"{duration:g}", flag]


def run_one(args: list[str], timeout_s: float) -> tuple[dict[str, Any], float]:
    """Run ``fleet <args>``; the report as a dict and the wall seconds it took."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        extra = ["--report", str(report), "--endpoint", f"tcp/127.0.0.1:{_free_port()}"]
        extra += ["--speed", "0", "--no-live"] if args[0] == "run" else ["--out", str(Path(tmp) / "lt")]
        cmd = [sys.executable, "-m", "fleet.cli", *args, *extra]
        t0 = time.monotonic()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout_s)
        wall = time.monotonic() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
        return dict(json.loads(report.read_text())), wall


def row(r: dict[str, Any], backend: str, traffic: bool, wall: float) -> str:
    """One Markdown row of the table from a run report."""

    def f(x: object, fmt: str) -> str:
        return "–" if x is None else format(x, fmt)

    dl = r["deadlocks"] if backend != "sumo" else f"{r.get('teleports')} teleports"
    cells = [
        str(r["robots"]),
        backend,
        "on" if traffic else "off",
        str(r["laps_completed"]),
        f(r["throughput_laps_per_robot_hour"], ".2f"),
        f(r.get("mean_wait_s"), ".0f"),
        f(r.get("p95_wait_s"), ".0f"),
        f(r.get("idle_fraction"), ".0%"),
        f(r.get("min_battery"), ".1%"),
        str(r["collisions"]),
        str(dl),
        f"{wall:.0f}",
    ]
    return "| " + " | ".join(cells) + " |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[6, 30, 100], help="robot counts")
    ap.add_argument("--duration", type=float, default=1800.0, help="simulated seconds per run")
    ap.add_argument("--no-sumo", action="store_true", help="leave out the SUMO rows")
    ap.add_argument("--timeout", type=float, default=4 * 3600.0, help="wall seconds per run at most")
    args = ap.parse_args(argv)
    print(HEAD)
    print("|" + "---|" * (HEAD.count("|") - 1), flush=True)
    for n in args.sizes:
        runs = [("sim", True), ("sim", False)] + ([] if args.no_sumo else [("sumo", False)])
        for backend, traffic in runs:
            r, wall = run_one(command(n, args.duration, backend, traffic), args.timeout)
            print(row(r, backend, traffic, wall), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
