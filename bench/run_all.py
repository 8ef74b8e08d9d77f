"""Run every benchmark in ``bench/`` with small sizes (``make bench``; a few minutes in all).

Each benchmark runs in its own process (``sys.executable bench/<script> <args>``) with a
timeout (on a timeout its whole process group is killed); its output is printed as it finishes, with the wall time it took. A benchmark that
fails (non-zero exit, a timeout, a missing optional dependency) is reported and the others
still run; the exit status is 1 if any failed.

Sizes: the scripts in :data:`SMALL_ARGS` get the arguments listed there. Of those arguments
only the options that the script's ``--help`` mentions are passed (so a script whose options
changed still runs, with its defaults). A script whose ``--help`` offers ``--quick`` gets
``--quick`` instead. Any other ``bench/*.py`` runs with its defaults.

    python bench/run_all.py                 # everything, small sizes
    python bench/run_all.py --list          # what would run, with the arguments
    python bench/run_all.py --only bench_bt bench_zenoh --timeout 300
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
ROOT = BENCH_DIR.parent

#: Small sizes for ``make bench`` (script name -> arguments). Order = run order.
SMALL_ARGS: dict[str, list[str]] = {
    "bench_bt.py": ["--trees", "200", "--seconds", "2"],
    "bench_coordinator.py": ["--routes", "200", "--robots", "200", "--cycles", "20"],
    "bench_zenoh.py": ["--robots", "200", "--hz", "10", "--seconds", "3", "--publishers", "1"],
    "bench_task_events.py": ["--robots", "200", "--events", "300"],
    "bench_secure_bus.py": ["--robots", "5", "--messages", "500", "--fleet", "100"],
    "status_bus.py": ["--robots", "1000", "--hz", "10", "--seconds", "3", "--workers", "2"],
    "sumo_steps.py": ["--robots", "200", "--steps", "300"],
    "bench_sim.py": ["--robots", "200", "--steps", "200"],
    "sim_vs_sumo.py": ["--robots", "200", "--steps", "200"],
    "bench_ros_scale.py": ["--robots", "20"],
    "bench_demo.py": ["--duration", "300"],
    "outcome_table.py": ["--sizes", "6", "--duration", "120"],
    "bench_scale.py": ["--sizes", "30", "--duration", "20"],
    "bench_quiet.py": ["--robots", "50", "--warmup", "5", "--periods", "5"],
    "bench_oncoming.py": ["--robots", "50", "--duration", "10"],
    "profile_loop.py": ["--robots", "30", "--duration", "5", "--top", "15"],
    "bench_traffic_scale.py": ["--robots", "200", "--sources", "10", "--joins", "50"],
    "traffic_time.py": ["--duration", "120"],
    "charging_wave.py": ["--robots", "30", "--duration", "60", "--every", "30"],
    "soak.py": ["--robots", "20", "--duration", "120", "--every", "20"],
    "chaos.py": ["--robots", "3", "--duration", "120", "--speed", "5", "--every", "4"],
}
#: Never run as benchmarks.
SKIP = {"run_all.py", "__init__.py"}


def discover() -> list[str]:
    """Benchmark scripts in ``bench/``: the known ones first (in :data:`SMALL_ARGS` order)."""
    present = sorted(
        p.name for p in BENCH_DIR.glob("*.py") if p.name not in SKIP and not p.name.startswith("_")
    )
    known = [s for s in SMALL_ARGS if s in present]
    return known + [s for s in present if s not in SMALL_ARGS]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def options_of(script: str) -> set[str] | None:
    """The ``--options`` a script's ``--help`` mentions (``None`` if ``--help`` fails)."""
    try:
        p = subprocess.run(
            [sys.executable, str(BENCH_DIR / script), "--help"],
            capture_output=True,
            text=True,
            timeout=60,
            env=_env(),
            cwd=ROOT,
        )
    except subprocess.TimeoutExpired:
        return None
    if p.returncode != 0:
        return None
    return set(re.findall(r"--[A-Za-z][\w-]*", p.stdout))


def args_for(script: str) -> list[str]:
    """Arguments for ``script`` (see the module docstring)."""
    want = SMALL_ARGS.get(script)
    if want is None:
        return []
    opts = options_of(script)
    if opts is None:
        return list(want)
    if "--quick" in opts:
        return ["--quick"]
    out: list[str] = []
    i = 0
    while i < len(want):
        flag = want[i]
        has_value = i + 1 < len(want) and not want[i + 1].startswith("--")
        if flag in opts:
            out.append(flag)
            if has_value:
                out.append(want[i + 1])
        i += 2 if has_value else 1
    return out


def run_one(script: str, args: list[str], timeout: float) -> tuple[bool, float, str]:
    """Run one benchmark; returns (ok, wall seconds, combined output)."""
    cmd = [sys.executable, str(BENCH_DIR / script), *args]
    t0 = time.monotonic()
    # own process group: a timeout also ends the benchmark's own children (e.g. publishers)
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_env(),
        cwd=ROOT,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=timeout)
        ok = proc.returncode == 0
        if not ok:
            out += f"\n[exit status {proc.returncode}]"
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        out, _ = proc.communicate()
        ok = False
        out = (out or "") + f"\n[timed out after {timeout:g} s; killed]"
    return ok, time.monotonic() - t0, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Run every benchmark in bench/ with small sizes, one process each; exit 1 if any failed.",
    )
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only these scripts (with or without .py)")
    ap.add_argument("--timeout", type=float, default=150.0, help="per-benchmark timeout, s (default 150)")
    ap.add_argument("--list", action="store_true", help="print what would run and exit")
    a = ap.parse_args(argv)
    scripts = discover()
    if a.only:
        wanted = {n if n.endswith(".py") else f"{n}.py" for n in a.only}
        unknown = wanted - set(scripts)
        if unknown:
            ap.error(
                f"no such benchmark in bench/: {', '.join(sorted(unknown))} (have: {', '.join(scripts)})"
            )
        scripts = [s for s in scripts if s in wanted]
    plan = [(s, args_for(s)) for s in scripts]
    if a.list:
        for s, args in plan:
            print(f"{s} {' '.join(args)}".rstrip())
        return 0
    results: list[tuple[str, bool, float]] = []
    t_all = time.monotonic()
    for i, (s, args) in enumerate(plan, 1):
        print(f"=== [{i}/{len(plan)}] {s} {' '.join(args)}".rstrip(), flush=True)
        ok, wall, out = run_one(s, args, a.timeout)
        print(out.rstrip())
        print(f"--- {s}: {'ok' if ok else 'FAILED'} in {wall:.1f} s\n", flush=True)
        results.append((s, ok, wall))
    failed = [s for s, ok, _ in results if not ok]
    print(f"=== summary ({time.monotonic() - t_all:.0f} s)")
    for s, ok, wall in results:
        print(f"  {'ok    ' if ok else 'FAILED'} {wall:7.1f} s  {s}")
    if failed:
        print(f"{len(failed)} of {len(results)} benchmark(s) failed: {', '.join(failed)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
