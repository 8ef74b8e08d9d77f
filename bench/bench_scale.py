"""Whole-fleet speed at scale: real-time factor of ``fleet loadtest`` (simulator + one behaviour
tree per robot + coordinator + traffic management + Zenoh status, one process) with trees
ticked on change (``--ticking event``, the default) against trees ticked every period
(``clock``), in one run so the ratio is measured on the same machine load.

Each row is one load test in a subprocess (a fresh interpreter, its own loopback port) at
``--speed 0``: agents decide at ``--tick-hz`` (10 Hz, the shipped agent rate) and publish
their status at ``--status-hz``. Printed per row: real-time factor of the loop (simulated /
wall seconds, setup excluded), the loop's CPU seconds (all threads of the process) and simulated
seconds per CPU second (what the loop would reach with a core to itself: on a loaded machine
the wall-clock factor mostly measures the load), setup wall seconds, laps, collisions,
deadlocks, the share of agent periods spent working (not idle), and the tree ticks per agent
period (1.0 when every tree ticks every period).

    python bench/bench_scale.py                                   # 1000 robots, 60 s, both modes
    python bench/bench_scale.py --sizes 1000 10000 --duration 30 --modes event
    python bench/bench_scale.py --sizes 100 --duration 30         # a quick look
    python bench/bench_scale.py --modes event --against /tmp/base # this checkout against another

``--against DIR`` runs every row twice, first with the code of another checkout ``DIR`` (e.g.
``git archive <commit> | tar -x -C DIR``), then with this one, one after the other on the
same machine, and prints the ratio of their loop CPU seconds and whether the two runs made the
same decisions (laps, collisions, deadlocks and each robot's distance driven equal).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
HEAD = (
    "| robots | ticking | traffic | sim s | loop wall s | x real time | loop CPU s | x real time per core | "
    "setup s | laps | collisions | deadlocks | working | tree ticks / period |"
)


def run_one(n: int, mode: str, args: argparse.Namespace, out: Path, code: Path = ROOT) -> dict[str, Any]:
    """One load test in a subprocess running the checkout ``code``; its report as a dict
    (``{}`` if it failed)."""
    cmd = [
        sys.executable,
        "-m",
        "fleet.cli",
        "loadtest",
        "--robots",
        str(n),
        "--duration",
        str(args.duration),
        "--tick-hz",
        str(args.tick_hz),
        "--status-hz",
        str(args.status_hz),
        "--ticking",
        mode,
        "--out",
        str(out),
        "--dpi",
        "40",
        "--seed",
        str(args.seed),
    ]
    if not args.traffic:
        cmd.append("--no-traffic")
    t0 = time.monotonic()
    env = {**os.environ, "PYTHONPATH": str(code)}
    done = subprocess.run(cmd, cwd=code, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        print(f"<!-- {n} robots, {mode}: exit {done.returncode}: {done.stderr[-500:]} -->", flush=True)
        return {}
    data: dict[str, Any] = json.loads((out / "report.json").read_text())
    data["_wall_total"] = time.monotonic() - t0
    return data


def outcome(d: dict[str, Any]) -> tuple[object, ...]:
    """What a run decided: laps, collisions, deadlocks and each robot's distance driven (m)."""
    per = d.get("per_robot", [])
    dist = tuple(sorted((str(r["name"]), round(float(r.get("distance_m", 0.0)), 6)) for r in per))
    return (d["laps_completed"], d["collisions"], d["deadlocks"], dist)


def compare(n: int, mode: str, args: argparse.Namespace, tmp: Path) -> None:
    """Run ``--against``'s code and this checkout's for one row; print both and the ratio."""
    base = run_one(n, mode, args, tmp / f"{n}-{mode}-base", Path(args.against).resolve())
    new = run_one(n, mode, args, tmp / f"{n}-{mode}-new")
    for label, d in (("before", base), ("after", new)):
        if d:
            print(row(n, f"{mode} ({label})", args.traffic, d), flush=True)
    if base and new:
        cpu_b, cpu_n = base["loadtest"]["loop_cpu_s"], new["loadtest"]["loop_cpu_s"]
        ob, on = outcome(base), outcome(new)
        same = ob == on
        moved = sum(1 for a, b in zip(ob[3], on[3], strict=False) if a != b)
        print(
            f"<!-- {n} robots, {mode}: loop CPU s before / after = {cpu_b / max(cpu_n, 1e-9):.2f}x, "
            f"wall x real time {base['loadtest']['real_time_factor']:.2f} -> "
            f"{new['loadtest']['real_time_factor']:.2f}; same decisions: "
            f"{'yes' if same else f'NO ({moved} robots drove another distance)'} -->",
            flush=True,
        )


def row(n: int, mode: str, traffic: bool, d: dict[str, Any]) -> str:
    lt = d["loadtest"]
    periods = max(1, int(lt.get("agent_periods", 0)))
    working = 1.0 - float(d.get("idle_fraction", 0.0))
    return (
        f"| {n} | {mode} | {'on' if traffic else 'off'} | {d['sim_time_s']:.0f} | "
        f"{d['wall_time_s'] - lt.get('setup_wall_s', 0.0):.1f} | {lt['real_time_factor']:.2f} | "
        f"{lt.get('loop_cpu_s', 0.0):.1f} | {lt.get('sim_s_per_cpu_s') or 0.0:.2f} | "
        f"{lt.get('setup_wall_s', 0.0):.1f} | {d['laps_completed']} | {d['collisions']} | {d['deadlocks']} | "
        f"{working:.0%} | {int(lt.get('tree_ticks', 0)) / periods:.3f} |"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[1000], help="robot counts (default 1000)")
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run (default 60)")
    p.add_argument("--modes", nargs="+", default=["clock", "event"], choices=["clock", "event"])
    p.add_argument("--tick-hz", type=float, default=10.0, help="agent decision rate (default 10)")
    p.add_argument("--status-hz", type=float, default=1.0, help="status publishing rate (default 1)")
    p.add_argument("--no-traffic", dest="traffic", action="store_false", help="without traffic management")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--against", metavar="DIR", help="also run another checkout's code, before this one's")
    args = p.parse_args(argv)
    print(
        f"tick {args.tick_hz:g} Hz, status {args.status_hz:g} Hz, {args.duration:g} s simulated per run",
        flush=True,
    )
    print(HEAD)
    print("|" + "---|" * (HEAD.count("|") - 1), flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        for n in args.sizes:
            if args.against:
                for mode in args.modes:
                    compare(n, mode, args, Path(tmp))
                continue
            factors: dict[str, float] = {}
            per_cpu: dict[str, float] = {}
            for mode in args.modes:
                d = run_one(n, mode, args, Path(tmp) / f"{n}-{mode}")
                if d:
                    print(row(n, mode, args.traffic, d), flush=True)
                    factors[mode] = float(d["loadtest"]["real_time_factor"])
                    per_cpu[mode] = float(d["loadtest"].get("sim_s_per_cpu_s") or 0.0)
            if "clock" in factors and "event" in factors and factors["clock"] > 0:
                cpu_ratio = per_cpu["event"] / per_cpu["clock"] if per_cpu.get("clock") else 0.0
                print(
                    f"<!-- {n} robots: event / clock real-time factor = "
                    f"{factors['event'] / factors['clock']:.2f}x, per CPU second {cpu_ratio:.2f}x -->",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
