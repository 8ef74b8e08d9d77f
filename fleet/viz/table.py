"""The live fleet table: one row per robot from its latest status record.

:func:`render_table` returns plain text with fixed-width columns: robot, pose (x, y in m,
yaw in degrees), battery %, charging, behavior-tree status and active leaf, mode, task id,
laps, lap progress and flags (``STUCK``; ``DEAD`` when the robot's liveliness token is gone;
``SILENT`` when its last record is more than ``silent_s`` simulated seconds older than
``now``). Up to 29 robots fit 100 columns one per line; from 30 robots on, a compact
layout puts two robots per line.

:class:`LiveTable` redraws the table in place on a TTY (ANSI cursor-up) at most every
``min_interval_s`` wall seconds, or prints one summary line every ``line_every_s`` wall
seconds when the output is not a TTY.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TextIO

#: From this many robots on, the table uses the two-per-line compact layout.
COMPACT_FROM = 30
#: A record this many simulated seconds older than ``now`` is flagged SILENT.
SILENT_S = 5.0

_BT_SHORT = {"RUNNING": "RUN", "SUCCESS": "OK", "FAILURE": "FAIL", "INVALID": "-"}


def robot_sort_key(name: str) -> tuple[str, int, str]:
    """Natural order: ``robot2`` before ``robot10``."""
    head = name.rstrip("0123456789")
    tail = name[len(head) :]
    return (head, int(tail) if tail else -1, name)


def _records(records: Mapping[str, Any] | Iterable[Any]) -> dict[str, Any]:
    if isinstance(records, Mapping):
        return dict(records)
    out: dict[str, Any] = {}
    for r in records:
        rec: Any = r
        out[rec.robot] = rec
    return out


def _cut(text: str, width: int) -> str:
    text = str(text)
    return text if len(text) <= width else text[: width - 1] + "~"


def _num(v: float, width: int, digits: int = 1) -> str:
    s = f"{v:.{digits}f}"
    if len(s) > width:
        s = f"{v:.0f}"
    return s.rjust(width)


def _flags(name: str, rec: Any, alive: set[str] | None, now: float | None, silent_s: float) -> str:
    out = []
    if rec is not None and rec.stuck:
        out.append("STUCK")
    if alive is not None and name not in alive:
        out.append("DEAD")
    elif rec is not None and now is not None and now - rec.t > silent_s:
        out.append("SILENT")
    return " ".join(out)


def summary_line(
    records: Mapping[str, Any] | Iterable[Any], alive: set[str] | None = None, now: float | None = None
) -> str:
    """One line: robot count, alive count, time, laps, charging, stuck and dead robots."""
    recs = _records(records)
    names = set(recs) | (alive or set())
    if now is None:
        now = max((r.t for r in recs.values()), default=0.0)
    laps = sum(int(r.laps) for r in recs.values())
    charging = sum(1 for r in recs.values() if r.charging)
    stuck = sum(1 for r in recs.values() if r.stuck)
    dead = len(set(recs) - alive) if alive is not None else 0
    alive_text = f", {len(alive)} alive" if alive is not None else ""
    return (
        f"fleet t={now:.1f} s: {len(names)} robots{alive_text}, laps {laps}, "
        f"charging {charging}, stuck {stuck}, dead {dead}"
    )


def render_table(
    records: Mapping[str, Any] | Iterable[Any],
    alive: set[str] | None = None,
    now: float | None = None,
    *,
    silent_s: float = SILENT_S,
    compact: bool | None = None,
) -> str:
    """The fleet table as text (no trailing newline).

    ``records``: latest :class:`~fleet.bus.status_bus.StatusRecord` per robot (a mapping by name
    or an iterable); ``alive``: robots whose liveliness token is held (``None``: unknown, no
    DEAD flags); ``now``: simulated seconds (default: the newest record's ``t``). Robots that
    are alive but never sent a status get a row too. ``compact`` forces a layout.
    """
    recs = _records(records)
    if now is None:
        now = max((r.t for r in recs.values()), default=0.0)
    names = sorted(set(recs) | (alive or set()), key=robot_sort_key)
    use_compact = len(names) >= COMPACT_FROM if compact is None else compact
    lines = [summary_line(recs, alive, now)]
    if not names:
        lines.append("(no robots seen yet)")
        return "\n".join(lines)
    if use_compact:
        cells = [_compact_cell(n, recs.get(n), alive, now, silent_s) for n in names]
        head = f"{'robot':<9} {'x':>5} {'y':>5} {'bat':>4} {'mode':<8} {'lap':>3} {'flag':<5}"
        lines.append(f"{head} | {head}".rstrip())
        for i in range(0, len(cells), 2):
            pair = cells[i : i + 2]
            lines.append(" | ".join(pair).rstrip())
        return "\n".join(lines)
    lines.append(
        f"{'robot':<9} {'x':>6} {'y':>6} {'yaw':>4} {'bat':>4} {'chg':<3} {'bt':<4} {'leaf':<16} "
        f"{'mode':<8} {'task':<10} {'laps':>4} {'prog':>4} flags"
    )
    for n in names:
        rec = recs.get(n)
        if rec is None:
            lines.append(f"{_cut(n, 9):<9} (no status yet) {_flags(n, None, alive, now, silent_s)}".rstrip())
            continue
        if rec.pose is not None:
            x, y, th = rec.pose
            pose = f"{_num(x, 6)} {_num(y, 6)} {math.degrees(th):4.0f}"
        else:
            pose = f"{'-':>6} {'-':>6} {'-':>4}"
        lines.append(
            f"{_cut(n, 9):<9} {pose} {rec.battery * 100:3.0f}% {'yes' if rec.charging else '':<3} "
            f"{_BT_SHORT.get(rec.bt, _cut(rec.bt, 4)):<4} {_cut(rec.leaf, 16):<16} {_cut(rec.mode, 8):<8} "
            f"{_cut(rec.task_id or '-', 10):<10} {rec.laps:>4} {rec.progress * 100:3.0f}% "
            f"{_flags(n, rec, alive, now, silent_s)}".rstrip()
        )
    return "\n".join(lines)


def _compact_cell(name: str, rec: Any, alive: set[str] | None, now: float, silent_s: float) -> str:
    flags = _flags(name, rec, alive, now, silent_s)
    flag = {"STUCK": "STUCK", "DEAD": "DEAD", "SILENT": "SLNT"}.get(flags.split(" ")[-1], "") if flags else ""
    if "DEAD" in flags:
        flag = "DEAD"
    if rec is None:
        return f"{_cut(name, 9):<9} {'-':>5} {'-':>5} {'-':>4} {'-':<8} {'-':>3} {flag:<5}"
    x, y = (rec.pose[0], rec.pose[1]) if rec.pose is not None else (math.nan, math.nan)
    xs = _num(x, 5) if rec.pose is not None else f"{'-':>5}"
    ys = _num(y, 5) if rec.pose is not None else f"{'-':>5}"
    return (
        f"{_cut(name, 9):<9} {xs} {ys} {rec.battery * 100:3.0f}% {_cut(rec.mode, 8):<8} "
        f"{min(rec.laps, 999):>3} {flag:<5}"
    )


class LiveTable:
    """Shows the fleet table on ``out`` as it changes (see the module docstring).

    ``tty`` defaults to ``out.isatty()``; ``wall`` is a monotonic clock (seconds).
    """

    def __init__(
        self,
        out: TextIO,
        *,
        min_interval_s: float = 0.5,
        line_every_s: float = 5.0,
        tty: bool | None = None,
        wall: Callable[[], float] = time.monotonic,
    ) -> None:
        self.out = out
        self.tty = bool(out.isatty()) if tty is None else tty
        self.min_interval_s = min_interval_s
        self.line_every_s = line_every_s
        self._wall = wall
        self._last: float | None = None
        self._lines = 0
        self.draws = 0

    def update(
        self,
        records: Mapping[str, Any] | Iterable[Any],
        alive: set[str] | None = None,
        now: float | None = None,
        *,
        force: bool = False,
    ) -> bool:
        """Redraw (TTY) or print a summary line (not a TTY) if enough wall time passed since
        the last one (or ``force``). Returns whether something was written."""
        w = self._wall()
        every = self.min_interval_s if self.tty else self.line_every_s
        if not force and self._last is not None and w - self._last < every:
            return False
        self._last = w
        if self.tty:
            text = render_table(records, alive, now)
            prefix = f"\x1b[{self._lines}F\x1b[J" if self._lines else ""
            self.out.write(prefix + text + "\n")
            self._lines = text.count("\n") + 1
        else:
            self.out.write(summary_line(records, alive, now) + "\n")
        self.out.flush()
        self.draws += 1
        return True

    def close(self) -> None:
        """Nothing to release; the last table stays on screen."""
        try:
            self.out.flush()
        except Exception:  # noqa: BLE001 - a closed stream
            pass
