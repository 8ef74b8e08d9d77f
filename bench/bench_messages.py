"""Cost of the wire codec: microseconds to build, encode (send) and decode (receive) one status
record and one task message, now and with the hand-written codec it replaced, in one process.

The baseline is ``fleet/messages.py`` as of ``--baseline`` (a git revision of this repository,
default ``3e8173b``, the last one with the hand-written codec), loaded from ``git show`` into a
module of its own; both codecs see the same values. Each figure is the best of ``--repeat``
runs of ``--number`` calls (the least disturbed by other work on a shared machine); compare
the ratios, not the microseconds, between runs.

    python bench/bench_messages.py
    python bench/bench_messages.py --number 20000 --repeat 7 --json
    python bench/bench_messages.py --baseline none      # the current codec only
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import timeit
import types
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import fleet.messages as current
from fleet.types import Pose2D

ROOT = Path(__file__).resolve().parent.parent

#: The last revision whose ``fleet/messages.py`` validated by hand (``as_float`` / ``req``).
DEFAULT_BASELINE = "3e8173b"

STATUS_FIELDS = {
    "robot": "robot12",
    "ns": "/robot12",
    "t": 123.45,
    "pose": (12.25, 7.5, 1.5708),
    "battery": 0.83,
    "charging": False,
    "stuck": False,
    "bt": "RUNNING",
    "leaf": "FollowRoute",
    "mode": "patrol",
    "task_id": "p-0003",
    "laps": 2,
    "progress": 0.4,
    "distance_m": 123.4,
    "collisions": 0,
    "seq": 17,
    "picks_done": 0,
}

TASK_ARGS = (
    "p-0003",
    "patrol",
    "robot12",
    "aisle_loop_1",
    (Pose2D(3.0, 3.0, 0.0), Pose2D(20.0, 3.0, 1.571), Pose2D(20.0, 9.0, 3.142), Pose2D(3.0, 9.0, -1.571)),
    Pose2D(1.0, 1.0, 0.0),
)


@dataclass(frozen=True)
class Row:
    """One operation: µs per message before (``None`` without a baseline) and after."""

    name: str
    before_us: float | None
    after_us: float

    @property
    def ratio(self) -> float | None:
        return None if self.before_us is None else self.before_us / self.after_us


def load_baseline(rev: str) -> types.ModuleType:
    """``fleet/messages.py`` at ``rev`` as a module named ``baseline_messages``."""
    src = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{rev}:fleet/messages.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    mod = types.ModuleType("baseline_messages")
    sys.modules[mod.__name__] = mod  # dataclasses look their module up
    exec(compile(src, f"{rev}:fleet/messages.py", "exec"), mod.__dict__)  # noqa: S102 - our own file
    return mod


def operations(m: types.ModuleType) -> dict[str, Callable[[], object]]:
    """The timed calls against codec module ``m``."""
    rec = m.StatusRecord(**STATUS_FIELDS)
    idle = m.StatusRecord(**{**STATUS_FIELDS, "pose": None, "task_id": None, "mode": "idle"})
    status_bytes = rec.to_json()
    task = m.TaskMessage(*TASK_ARGS)
    task_bytes = task.to_json()
    return {
        "status build": lambda: m.StatusRecord(**STATUS_FIELDS),
        "status encode (send)": rec.to_json,
        "idle status encode (send)": idle.to_json,
        "status decode (receive)": lambda: m.StatusRecord.from_json(status_bytes),
        "task encode (send)": task.to_json,
        "task decode (receive)": lambda: m.TaskMessage.from_json(task_bytes),
    }


def best_us(fn: Callable[[], object], number: int, repeat: int) -> float:
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def run(baseline: str | None, number: int, repeat: int) -> list[Row]:
    before = operations(load_baseline(baseline)) if baseline else {}
    after = operations(current)
    rows = []
    for name, fn in after.items():
        b = best_us(before[name], number, repeat) if name in before else None
        rows.append(Row(name, b, best_us(fn, number, repeat)))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="µs per message to build, encode and decode a status record and a task message: "
        "the msgspec codec against the hand-written one it replaced (same process, same values)."
    )
    ap.add_argument("--baseline", default=DEFAULT_BASELINE, help="git revision of the old codec, or 'none'")
    ap.add_argument("--number", type=int, default=5000, help="calls per timing run (default 5000)")
    ap.add_argument("--repeat", type=int, default=5, help="timing runs, the best counts (default 5)")
    ap.add_argument("--quick", action="store_true", help="1000 calls x 3 runs (for make bench)")
    ap.add_argument("--json", action="store_true", help="also print the rows as one JSON line")
    a = ap.parse_args(argv)
    number, repeat = (1000, 3) if a.quick else (a.number, a.repeat)
    if number < 1 or repeat < 1:
        ap.error("--number and --repeat must be positive")
    baseline = None if a.baseline.lower() == "none" else a.baseline
    try:
        rows = run(baseline, number, repeat)
    except subprocess.CalledProcessError as e:
        print(f"bench_messages: cannot read the baseline {baseline!r}: {e.stderr.strip()}", file=sys.stderr)
        return 1
    size = len(current.StatusRecord(**STATUS_FIELDS).to_json())
    print(
        f"bench_messages: µs per message, best of {repeat} x {number} calls; "
        f"before = fleet/messages.py at {baseline or '-'}, after = msgspec structs ({size}-byte status)"
    )
    print(f"  {'':26s} {'before':>8s} {'after':>8s} {'ratio':>7s}")
    for r in rows:
        before = "-" if r.before_us is None else f"{r.before_us:8.2f}"
        ratio = "-" if r.ratio is None else f"{r.ratio:6.1f}x"
        print(f"  {r.name:26s} {before:>8s} {r.after_us:8.2f} {ratio:>7s}")
    if a.json:
        print(json.dumps([{**asdict(r), "ratio": r.ratio} for r in rows]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
