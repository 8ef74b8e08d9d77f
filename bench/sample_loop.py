"""Where a large load test's loop spends its time, without a profiler's overhead: ``fleet
loadtest`` run in this process while a thread samples the main thread's stack every
``--interval-ms`` once the runner's loop has started (set-up excluded), plus the loop's rate.

    nice -n 10 python bench/sample_loop.py --robots 10000 --duration 30 --wall-limit 1800

Prints the set-up lines, then every ``--report-s`` wall seconds the simulated time reached and
the simulated seconds per wall and per process-CPU second since the last line, and at the end
the share of the samples in which each named part of the loop (``profile_loop.PARTS``) was on
the stack, the functions most often on the stack (inclusive) and on top of it (own time).
``--wall-limit`` stops the run (as Ctrl-C does: the report is written, marked interrupted)
after that many wall seconds of the loop. cProfile (``bench/profile_loop.py``) slows a
10,000-robot loop several times over and its own cost falls on the many small Python calls;
sampling does not, but it sees only where the main thread is, not how often a function ran.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from profile_loop import PARTS  # noqa: E402


def _short(frame: FrameType) -> str:
    code = frame.f_code
    parts = code.co_filename.replace("\\", "/").split("/")
    return f"{'/'.join(parts[-2:])}:{code.co_name}"


# long: one argument parser, a sampler thread and the printing of its tables
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=10000)
    p.add_argument("--duration", type=float, default=30.0, help="simulated seconds (default 30)")
    p.add_argument("--tick-hz", type=float, default=10.0)
    p.add_argument("--status-hz", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--interval-ms", type=float, default=20.0)
    p.add_argument("--report-s", type=float, default=60.0, help="wall seconds between rate lines")
    p.add_argument("--wall-limit", type=float, default=0.0, help="stop after this many loop wall s (0: none)")
    p.add_argument("--top", type=int, default=30)
    p.add_argument("--window-top", type=int, default=30, help="functions listed with each rate line")
    args = p.parse_args(argv)

    from fleet.loadtest.run import run_loadtest
    from fleet.runtime import runner

    main_id = threading.get_ident()
    started = threading.Event()
    done = threading.Event()
    holder: dict[str, Any] = {}
    inclusive: collections.Counter[str] = collections.Counter()
    own: collections.Counter[str] = collections.Counter()
    total = [0]
    window: collections.Counter[str] = collections.Counter()
    window_n = [0]
    loop = runner.FleetRunner._loop

    def sampled(self: runner.FleetRunner, world: Any) -> None:
        holder["world"] = world
        holder["runner"] = self
        started.set()
        try:
            loop(self, world)
        finally:
            done.set()  # samples of the loop only, not of the report and plots after it

    def sample() -> None:
        started.wait()
        w0, c0 = time.monotonic(), time.process_time()
        clock = holder["world"].clock
        last = (w0, c0, clock.now())
        print(f"loop started at t={last[2]:.2f} s (process CPU {c0:.0f} s)", flush=True)
        while not done.wait(args.interval_ms / 1000.0):
            frame = sys._current_frames().get(main_id)
            if frame is not None:
                total[0] += 1
                own[_short(frame)] += 1
                seen: set[str] = set()
                f: FrameType | None = frame
                while f is not None:
                    seen.add(_short(f))
                    f = f.f_back
                inclusive.update(seen)
                window.update(seen)
                window_n[0] += 1
            w, c = time.monotonic(), time.process_time()
            if w - last[0] >= args.report_s:
                t = clock.now()
                dt = t - last[2]
                print(
                    f"loop {w - w0:.0f} wall s: t={t:.2f} simulated s; last {w - last[0]:.0f} wall s: "
                    f"{dt / (w - last[0]):.4f} sim s per wall s, {dt / max(c - last[1], 1e-9):.4f} per CPU s",
                    flush=True,
                )
                last = (w, c, t)
                for name, k in window.most_common(args.window_top):
                    print(f"    {k / max(window_n[0], 1):6.1%}  {name}", flush=True)
                window.clear()
                window_n[0] = 0
            if args.wall_limit and w - w0 >= args.wall_limit and not holder.get("stopped"):
                holder["stopped"] = True
                holder["runner"].stop()  # the run ends after this period, and reports
        holder["loop"] = (time.monotonic() - w0, time.process_time() - c0, clock.now())

    runner.FleetRunner._loop = sampled  # type: ignore[method-assign]
    th = threading.Thread(target=sample, daemon=True)
    th.start()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="sample-loop-") as tmp:
        res = run_loadtest(
            args.robots, args.duration, out_dir=Path(tmp), tick_hz=args.tick_hz, status_hz=args.status_hz,
            seed=args.seed, dpi=40, on_setup=lambda line: print(line, flush=True),
        )  # fmt: skip
        done.set()
        th.join()
    runner.FleetRunner._loop = loop  # type: ignore[method-assign]
    d = res.data
    wall, cpu, t_end = holder.get("loop", (0.0, 0.0, 0.0))
    print(
        f"{args.robots} robots, agents {args.tick_hz:g} Hz, status {args.status_hz:g} Hz, seed {args.seed}: "
        f"t={t_end:.2f} simulated s in {wall:.0f} loop wall s ({cpu:.0f} CPU s; {t_end / max(wall, 1e-9):.4f} "
        f"sim s per wall s, {t_end / max(cpu, 1e-9):.4f} per CPU s); laps {d['laps_completed']}, collisions "
        f"{d['collisions']}, deadlocks {d['deadlocks']}; {time.monotonic() - t0:.0f} wall s in all"
    )
    n = max(total[0], 1)
    print(f"\n{total[0]} samples of the main thread, {args.interval_ms:g} ms apart")
    print("\n| part of the loop (on the stack) | share |\n|---|---|")
    for label, (path, func) in PARTS.items():
        key = f"{'/'.join(path.split('/')[-2:])}:{func}"
        print(f"| {label} | {inclusive[key] / n:.0%} |")
    for title, counts in (("on the stack (inclusive)", inclusive), ("on top (own)", own)):
        print(f"\n-- {title} --")
        for name, k in counts.most_common(args.top):
            print(f"{k / n:6.1%}  {name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
