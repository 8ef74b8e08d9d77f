"""Where a load test's loop spends its time: ``fleet loadtest`` run in this process with the
runner's loop (``FleetRunner._loop``: agents, coordinator, traffic management, simulator, status
bus; set-up excluded) under cProfile, printed as the top functions by cumulative and by own
time, plus the loop's share of a few named parts (``--part``).

    python bench/profile_loop.py --robots 1000 --duration 15
    python bench/profile_loop.py --robots 1000 --duration 15 --save /tmp/loop.prof

``python -m cProfile -m fleet.cli loadtest ...`` writes nothing (the ``fleet`` entry point
leaves by ``os._exit``), hence this script. cProfile counts wall time, and other threads (the
Zenoh callbacks) take the interpreter from long pure-Python functions now and then, so a
function's own time can include theirs: read the shares, and time a suspect alone in thread CPU
(e.g. ``bench/bench_oncoming.py``).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import tempfile
import time
from pathlib import Path
from typing import Any

#: Named parts of the loop: a label -> (the end of the function's file path, its name).
PARTS = {
    "loop": ("runtime/runner.py", "_loop"),
    "coordinator cycle": ("coordination/coordinator.py", "cycle"),
    "- charger service (errands.serve_chargers)": ("traffic/errands.py", "serve_chargers"),
    "- assignments (CoordinatorState._assign)": ("coordination/state.py", "_assign"),
    "- traffic manager cycle": ("traffic/manager.py", "cycle"),
    "agents' periods (RobotAgent.period)": ("runtime/agent.py", "period"),
    "- tree ticks": ("runtime/agent.py", "_tick_tree"),
    "- state reads (LatchedBackend.robot_state)": ("runtime/latch.py", "robot_state"),
    "- status, publishing, observation (RobotAgent._report)": ("runtime/agent.py", "_report"),
    "scheduler (TickScheduler.due)": ("runtime/scheduler.py", "due"),
    "simulator steps": ("sim/simulator.py", "_step"),
    "task-service events (ServiceBus._on_event)": ("service/bus_face.py", "_on_event"),
    "bus publisher declarations (StatusBus._publisher)": ("bus/status_bus.py", "_publisher"),
}


def _cumulative(stats: pstats.Stats, where: tuple[str, str]) -> float:
    """Cumulative seconds of the function ``where`` (0 if it never ran)."""
    path, func = where
    total = 0.0
    for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        if name == func and file.replace("\\", "/").endswith(path):
            total = max(total, ct)
    return total


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=1000)
    p.add_argument("--duration", type=float, default=15.0, help="simulated seconds (default 15)")
    p.add_argument("--tick-hz", type=float, default=10.0)
    p.add_argument("--status-hz", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--top", type=int, default=40, help="functions listed per order (default 40)")
    p.add_argument("--save", metavar="FILE", help="also write the profile (pstats format)")
    args = p.parse_args(argv)

    from fleet.loadtest.run import run_loadtest
    from fleet.runtime import runner

    prof = cProfile.Profile()
    loop = runner.FleetRunner._loop

    def profiled(self: runner.FleetRunner, world: Any) -> None:
        prof.enable()
        try:
            loop(self, world)
        finally:
            prof.disable()

    runner.FleetRunner._loop = profiled  # type: ignore[method-assign]
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="profile-loop-") as tmp:
        res = run_loadtest(
            args.robots, args.duration, out_dir=Path(tmp), tick_hz=args.tick_hz, status_hz=args.status_hz,
            seed=args.seed, dpi=40,
        )  # fmt: skip
    runner.FleetRunner._loop = loop  # type: ignore[method-assign]
    if args.save:
        prof.dump_stats(args.save)
    d = res.data
    print(
        f"{args.robots} robots, {args.duration:g} simulated s, agents {args.tick_hz:g} Hz, status "
        f"{args.status_hz:g} Hz, seed {args.seed}: laps {d['laps_completed']}, collisions {d['collisions']}, "
        f"deadlocks {d['deadlocks']}; {time.monotonic() - t0:.0f} wall s in all"
    )
    stats = pstats.Stats(prof)
    whole = _cumulative(stats, PARTS["loop"])
    print("\n| part of the loop (cumulative, under the profiler) | s | share |\n|---|---|---|")
    for label, where in PARTS.items():
        s = _cumulative(stats, where)
        print(f"| {label} | {s:.1f} | {s / max(whole, 1e-9):.0%} |")
    for order in ("cumulative", "tottime"):
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats(order).print_stats(args.top)
        print(f"\n-- by {order} --")
        print("\n".join(line for line in buf.getvalue().splitlines() if line.strip()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
