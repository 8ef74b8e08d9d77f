"""Set-up of a load test by phase, at several fleet sizes: where the minutes before a big fleet
moves go, and how each phase grows with the fleet.

    python bench/bench_setup.py --sizes 1000 2000 5000

Each size runs in its own process (so the resident memory is that size's alone): the floor is
generated and loaded (:func:`fleet.loadtest.run.prepare_config`), then a
:class:`fleet.runtime.runner.FleetRunner` builds the world, the coordinator with traffic
management and one agent per robot, and runs its first agent period (every robot's first tick
and the coordinator's first cycle, which assigns every route). Prints one row per size: the
process's CPU seconds per phase (not wall seconds: the machine is shared), the growth against
the previous size (phase ratio / size ratio: 1.0 is linear, 2.0 at twice the size is
quadratic) and the resident memory once the first period is done (MB, and per robot in kB).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

PHASES = ("floor", "world", "coordinator", "agents", "first_period")


def one(n: int, out: Path, tick_hz: float) -> dict[str, float]:
    """Time the phases of one size in this process."""
    from fleet.bus.session import free_endpoint
    from fleet.loadtest.memory import rss_mb
    from fleet.loadtest.run import prepare_config
    from fleet.runtime.runner import FleetRunner
    from fleet.viz.display import NullDisplay

    t: dict[str, float] = {}
    c = time.process_time()
    cfg = prepare_config(n, out, tick_hz=tick_hz, status_hz=1.0)
    t["floor"] = time.process_time() - c
    runner = FleetRunner(
        cfg, duration=0.5 / tick_hz, speed=0.0, endpoint=free_endpoint(), live=False, display=NullDisplay()
    )
    marks: list[tuple[str, float]] = []  # (phase, process CPU s at its end)

    def on_setup(line: str) -> None:
        print(f"  {n}: {line}", file=sys.stderr, flush=True)
        if " ready in " in line:
            marks.append((line.split(":", 2)[1].strip(), time.process_time()))

    first: list[float] = []
    runner.on_setup = on_setup
    runner.observers.append(lambda _now, _r: first.append(time.process_time()) if not first else None)
    prev = time.process_time()
    runner.run()
    for name, at in marks:
        key = name.split()[0]
        t[key] = at - prev
        prev = at
    t["first_period"] = (first[0] if first else time.process_time()) - prev
    t["rss_mb"] = rss_mb()
    return t


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[1000, 2000, 5000])
    p.add_argument("--tick-hz", type=float, default=2.0)
    p.add_argument("--out", type=Path, default=Path("out/bench_setup"))
    p.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.one is not None:
        print(json.dumps(one(a.one, a.out / f"n{a.one}", a.tick_hz)))
        return 0
    rows: list[tuple[int, dict[str, float]]] = []
    print("robots | " + " | ".join(f"{k} CPU s" for k in PHASES) + " | total CPU s | RSS MB | kB/robot")
    for n in a.sizes:
        cmd = [sys.executable, __file__, "--one", str(n), "--out", str(a.out), "--tick-hz", str(a.tick_hz)]
        res = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, check=True)
        t = json.loads(res.stdout.strip().splitlines()[-1])
        total = sum(t.get(k, 0.0) for k in PHASES)
        cells = " | ".join(f"{t.get(k, 0.0):.1f}" for k in PHASES)
        print(f"{n} | {cells} | {total:.1f} | {t['rss_mb']:.0f} | {t['rss_mb'] * 1024 / n:.0f}", flush=True)
        if rows:
            n0, t0 = rows[-1]
            grow = " | ".join(
                f"{(t.get(k, 0.0) / t0[k]) / (n / n0):.2f}" if t0.get(k, 0.0) > 0.05 else "-" for k in PHASES
            )
            print(f"growth {n0}->{n} (phase ratio / size ratio) | {grow}", flush=True)
        rows.append((n, t))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
