"""CPU per robot of one quiet period: what a robot whose tree does not tick still costs every
agent period (reading its state, the safety watchdog, its status record and publishing decision,
the in-process coordinator taking the status in), measured on a running load-test fleet.

A load test of ``--robots`` robots (the floor of ``fleet loadtest``, agents at 10 Hz, status at
1 Hz, traffic management on) runs ``--warmup`` simulated seconds so that robots drive, charge
and wait; then, between two periods of the loop, every agent is ticked ``--periods`` more times
without its tree (``period(False)``, the event-driven scheduler's quiet period, as the runner
calls it) and the coordinator takes the statuses in (its cycle minus its decisions,
``state.step``); before each
round the scheduler decides once which trees would tick (``TickScheduler.due``). Each figure is
the thread CPU time of one such round divided by the robots, the least of the rounds (the figure
least disturbed by other work on a loaded machine).

    python bench/bench_quiet.py --robots 300
    python bench/bench_quiet.py --robots 300 --against /tmp/base   # another checkout, then this one

``--against DIR`` runs the same measurement with the code of ``DIR`` first (e.g.
``git archive <commit> | tar -x -C DIR``), then with this checkout's, each in a fresh process,
and prints the ratio of their figures. The whole loop's speed is ``bench/bench_scale.py``'s.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def measure(robots: int, warmup: float, periods: int, out: Path) -> dict[str, float]:
    """One measurement in this process (the code on ``sys.path``); the least per-robot CPU (us)."""
    from fleet.bus.session import free_endpoint
    from fleet.loadtest.run import prepare_config
    from fleet.runtime.runner import FleetRunner
    from fleet.viz.display import NullDisplay

    cfg = prepare_config(robots, out, tick_hz=10.0, status_hz=1.0)
    runner = FleetRunner(
        cfg, duration=warmup + 60.0, speed=0, endpoint=free_endpoint(), live=False, display=NullDisplay(),
        out=io.StringIO(),
    )  # fmt: skip
    got: dict[str, float] = {}

    def observe(now: float, r: FleetRunner) -> None:
        if now < warmup or got or r.coordinator is None:
            return
        coord = r.coordinator
        state = coord.state
        step = state.step
        spent = [0.0]

        def timed_step(at: float) -> Any:
            t = time.thread_time()
            try:
                return step(at)
            finally:
                spent[0] += time.thread_time() - t

        state.step = timed_step  # type: ignore[method-assign]
        agent_us, intake_us, due_us = [], [], []
        sched = r.scheduler
        for _ in range(periods):
            if sched is not None:
                t = time.thread_time()
                sched.due(now)
                due_us.append((time.thread_time() - t) / len(r.agents) * 1e6)
            t0 = time.thread_time()
            for a in r.agents:
                getattr(a, "period", a.tick)(False)  # the runner's call (tick() before it existed)
            t1 = time.thread_time()
            spent[0] = 0.0
            getattr(r, "_cycle", coord.cycle)()  # the runner's: the period's observations, then the cycle
            t2 = time.thread_time()
            agent_us.append((t1 - t0) / len(r.agents) * 1e6)
            intake_us.append((t2 - t1 - spent[0]) / len(r.agents) * 1e6)
        state.step = step  # type: ignore[method-assign]
        got.update(agent_us=min(agent_us), intake_us=min(intake_us), due_us=min(due_us, default=0.0), t=now)
        r.stop()

    runner.observers.append(observe)
    runner.run()
    return got


def run_in(code: Path, args: argparse.Namespace, out: Path) -> dict[str, float]:
    """The measurement in a fresh process with the code of the checkout ``code``."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--robots", str(args.robots), "--warmup"]
    cmd += [str(args.warmup), "--periods", str(args.periods), "--json", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(code)}
    done = subprocess.run(cmd, cwd=code, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{code}: exit {done.returncode}: {done.stderr[-800:]}")
    result: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=300, help="fleet size (default 300)")
    p.add_argument("--warmup", type=float, default=20.0, help="simulated s before measuring (default 20)")
    p.add_argument("--periods", type=int, default=20, help="quiet rounds measured (default 20)")
    p.add_argument("--against", metavar="DIR", help="also measure another checkout's code, first")
    p.add_argument("--json", action="store_true", help="print one JSON line (used by --against)")
    p.add_argument("--out", type=Path, help="where the floor is generated (default: a temporary directory)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-quiet-") as tmp:
        if args.json:
            print(json.dumps(measure(args.robots, args.warmup, args.periods, args.out or Path(tmp))))
            return 0
        rows = []
        if args.against:
            rows.append(("before", run_in(Path(args.against).resolve(), args, Path(tmp) / "before")))
        rows.append(("this checkout", run_in(ROOT, args, Path(tmp) / "after")))
        print(f"{args.robots} robots, quiet period after {args.warmup:g} s, least of {args.periods} rounds")
        print(
            "| code | scheduler us / robot | agent us / robot | coordinator intake us / robot | total us / robot |"
        )
        print("|---|---|---|---|---|")
        for label, d in rows:
            total = d["due_us"] + d["agent_us"] + d["intake_us"]
            print(
                f"| {label} | {d['due_us']:.1f} | {d['agent_us']:.1f} | {d['intake_us']:.1f} | {total:.1f} |"
            )
        if len(rows) == 2:
            b, a = (r[1]["due_us"] + r[1]["agent_us"] + r[1]["intake_us"] for r in rows)
            print(f"before / after: {b / max(a, 1e-9):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
