"""The displays of a running fleet: the live table redraws in place on a terminal (checked on a
small terminal emulator fed with what rich writes), summary / progress lines otherwise."""

from __future__ import annotations

import io
import re

from bus_peer import record
from rich.console import Console

from fleet.messages import StatusRecord
from fleet.viz.display import FleetSnapshot, LiveTable, ProgressDisplay, default_display, progress_line

_CSI = re.compile(r"\x1b\[(\??)(\d*)([A-Za-z])")


def screen(text: str, width: int, height: int) -> list[str]:
    """What a ``width`` x ``height`` terminal shows after ``text`` (cursor moves, line erases,
    wrapping and scrolling; colors and cursor visibility ignored)."""
    rows = [[" "] * width for _ in range(height)]
    r = c = 0
    i = 0

    def newline() -> None:
        nonlocal r
        r += 1
        if r == height:
            rows.pop(0)
            rows.append([" "] * width)
            r = height - 1

    while i < len(text):
        m = _CSI.match(text, i)
        if m:
            private, n, op = m.group(1), int(m.group(2) or 1), m.group(3)
            if not private and op == "A":
                r = max(0, r - n)
            elif not private and op == "K":
                rows[r] = [" "] * width
            i = m.end()
            continue
        ch = text[i]
        i += 1
        if ch == "\n":
            newline()
            c = 0
        elif ch == "\r":
            c = 0
        else:
            if c == width:
                newline()
                c = 0
            rows[r][c] = ch
            c += 1
    return ["".join(row).rstrip() for row in rows]


def recs(n: int, t: float) -> list[StatusRecord]:
    return [record(f"robot{i}", i) for i in range(1, n + 1)]


def snap(t: float, n: int = 30) -> FleetSnapshot:
    rs = recs(n, t)
    return FleetSnapshot(sim_time_s=t, wall_s=t / 5, records=rs, alive={r.robot for r in rs}, duration_s=30.0)


def test_live_table_redraws_in_place_at_80_and_160_columns() -> None:
    for width, height in ((80, 24), (160, 24), (80, 50), (160, 50)):
        buf = io.StringIO()
        console = Console(file=buf, width=width, height=height, force_terminal=True, color_system=None)
        table = LiveTable(buf, console=console)
        assert table.tty
        for k in range(1, 6):
            table.show(snap(float(k)))
        table.close(snap(6.0))
        shown = screen(buf.getvalue(), width, height)
        headlines = [line for line in shown if line.startswith("fleet t=")]
        assert headlines == ["fleet t=6.0 s: 30 robots, 30 alive, laps 33, charging 0, stuck 0, dead 0"], (
            width,
            height,
            shown,
        )
        assert table.draws == 6


def test_live_table_follows_the_terminal_height() -> None:
    buf = io.StringIO()
    console = Console(file=buf, width=80, height=12, force_terminal=True, color_system=None)
    table = LiveTable(buf, console=console)
    table.show(snap(1.0))
    table.show(snap(2.0))
    table.close()
    shown = [line for line in screen(buf.getvalue(), 80, 12) if line]
    assert shown[0].startswith("fleet t=2.0 s") and shown[-1].startswith("... ")
    assert len(shown) <= 11


def test_live_table_not_on_a_terminal_writes_summary_lines() -> None:
    buf = io.StringIO()
    table = LiveTable(buf, tty=False)
    assert table.interval_s == 5.0
    table.show(snap(1.0, 2))
    table.close(snap(2.0, 2))
    lines = buf.getvalue().splitlines()
    assert lines == [
        "fleet t=1.0 s: 2 robots, 2 alive, laps 0, charging 0, stuck 0, dead 0",
        "fleet t=2.0 s: 2 robots, 2 alive, laps 0, charging 0, stuck 0, dead 0",
    ]
    assert "\x1b" not in buf.getvalue()


def test_progress_lines_for_logs_and_a_bar_on_a_terminal() -> None:
    plain = io.StringIO()
    progress = ProgressDisplay(plain, tty=False)
    progress.show(FleetSnapshot(12.0, 5.0, recs(6, 12.0), laps=3, charging=1))
    progress.close(FleetSnapshot(13.0, 6.0))
    assert plain.getvalue() == "[t=   12.0 s sim,    5.0 s wall] 6 robots, 3 laps, 1 charging\n"
    line = progress_line(
        FleetSnapshot(
            314.5, 10.7, laps=102, collisions=0, deadlocks=26, states={"patrol": 18, "idle": 72, "dead": 0},
            real_time_factor=31.4, label="loadtest",
        )
    )  # fmt: skip
    assert (
        line
        == "[loadtest t=  314.5 s sim,   10.7 s wall, 31.40x real time] 102 laps, 0 collisions, 26 deadlocks; patrol 18, idle 72"
    )
    buf = io.StringIO()
    console = Console(file=buf, width=100, height=24, force_terminal=True, color_system=None)
    bar = ProgressDisplay(buf, console=console)
    for k in range(1, 4):
        bar.show(FleetSnapshot(10.0 * k, k, recs(6, 10.0 * k), duration_s=30.0, laps=k, real_time_factor=5.0))
    bar.close()
    shown = [line for line in screen(buf.getvalue(), 100, 24) if line]
    assert len(shown) == 1 and "t=30.0 s" in shown[0] and "3 laps" in shown[0] and "5.0x" in shown[0]


def test_default_display_is_the_table_on_a_terminal() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    assert isinstance(default_display(Tty()), LiveTable)
    assert isinstance(default_display(Tty(), live=False), ProgressDisplay)
    assert isinstance(default_display(io.StringIO()), ProgressDisplay)
    assert isinstance(default_display(io.StringIO(), live=True), LiveTable)
