"""The fleet table: the columns people need at 80 and 160 columns, one robot per line, side-by-side
panes or a "not shown" line when the robots do not fit the height, flags first."""

from __future__ import annotations

import msgspec
from bus_peer import record
from rich.console import Console

from fleet.messages import StatusRecord
from fleet.viz.table import FleetTable, render_table

ESSENTIAL = ("robot", "x", "y", "bat", "mode", "task", "laps", "flags")


def fleet(n: int) -> dict[str, StatusRecord]:
    """``n`` patrolling robots with coordinator-style task ids and a real leaf name."""
    return {
        f"robot{i}": msgspec.structs.replace(
            record(f"robot{i}", i), task_id=f"p-{i:04d}", leaf="GrantToCharger"
        )
        for i in range(1, n + 1)
    }


def draw(table: FleetTable, width: int) -> list[str]:
    """``table`` drawn on a plain rich console ``width`` columns wide."""
    console = Console(width=width, record=True, color_system=None, force_terminal=False)
    with console.capture() as cap:
        console.print(table)
    return cap.get().rstrip("\n").splitlines()


def header_cells(line: str) -> list[str]:
    return [c for c in line.replace("│", " ").split() if c]


def test_six_robots_one_per_line_with_every_column_and_flags() -> None:
    six = fleet(6)
    six["robot3"] = msgspec.structs.replace(six["robot3"], stuck=True)
    lines = render_table(six, alive=set(six) - {"robot6"}).splitlines()
    assert lines[0].startswith("fleet t=0.6 s: 6 robots, 5 alive") and "stuck 1, dead 1" in lines[0]
    cols = header_cells(lines[1])
    assert cols == [
        "robot",
        "x",
        "y",
        "yaw",
        "bat",
        "chg",
        "bt",
        "leaf",
        "mode",
        "task",
        "laps",
        "prog",
        "flags",
    ]
    assert len(lines) == 2 + 6
    assert lines[4].split()[0] == "robot3" and lines[4].endswith("STUCK")
    assert lines[7].split()[0] == "robot6" and lines[7].endswith("DEAD")
    assert "GrantToCharger" in lines[2] and "p-0001" in lines[2] and "90%" in lines[2]


def test_thirty_robots_at_80_columns_keep_the_essential_columns() -> None:
    lines = draw(FleetTable(fleet(30), alive=set(fleet(30))), 80)
    assert max(map(len, lines)) <= 80
    cols = header_cells(lines[1])
    assert all(c in cols for c in ESSENTIAL), cols
    assert "leaf" in cols and "prog" in cols
    assert len(lines) == 2 + 30  # one robot per line, every robot
    assert all(f"p-{i:04d}" in lines[1 + i] for i in range(1, 31))
    assert "GrantToCharger" in lines[2]  # the leaf is not cut at 80 columns


def test_thirty_robots_at_160_columns_show_every_column() -> None:
    lines = draw(FleetTable(fleet(30), alive=set(fleet(30))), 160)
    cols = header_cells(lines[1])
    assert cols == [
        "robot",
        "x",
        "y",
        "yaw",
        "bat",
        "chg",
        "bt",
        "leaf",
        "mode",
        "task",
        "laps",
        "prog",
        "flags",
    ]
    assert len(lines) == 2 + 30


def test_a_short_terminal_splits_into_panes_or_says_what_is_not_shown() -> None:
    robots = fleet(30)
    robots["robot29"] = msgspec.structs.replace(robots["robot29"], stuck=True)
    # 160 x 24: two panes of 15 robots, the essential columns in each
    lines = draw(FleetTable(robots, alive=set(robots), height=23), 160)
    assert len(lines) <= 23 and max(map(len, lines)) <= 160
    assert "│" in lines[1]
    left, right = (header_cells(part) for part in lines[1].split("│"))
    assert all(c in left for c in ESSENTIAL) and all(c in right for c in ESSENTIAL)
    shown = {w for line in lines[2:] for w in line.replace("│", " ").split() if w.startswith("robot")}
    assert shown == set(robots)
    # 80 x 12: no room for panes; the flagged robot is shown, the rest is counted
    lines = draw(FleetTable(robots, alive=set(robots) - {"robot30"}, height=12), 80)
    assert len(lines) <= 12
    names = [line.split()[0] for line in lines[2:-1]]
    assert "robot29" in names and "robot30" in names  # STUCK and DEAD come first
    assert lines[-1].startswith(f"... {30 - len(names)} more robots not shown")


def test_no_robots_and_robots_without_status() -> None:
    assert render_table({}, set()).endswith("(no robots seen yet)")
    text = render_table({}, {"robot1"})
    assert "robot1" in text and "(no status yet)" in text


def test_silent_robot_is_flagged() -> None:
    recs = fleet(2)
    lines = render_table(recs, now=recs["robot2"].t + 10.0).splitlines()
    assert lines[2].endswith("STALE") and lines[3].endswith("STALE")


def test_battery_is_unknown_before_the_robots_first_state() -> None:
    """A restarted agent's status before its robot's first state (no pose) carries the
    navigation client's default battery; the table shows ``?``, not that default."""
    recs = fleet(2)
    recs["robot2"] = msgspec.structs.replace(recs["robot2"], pose=None, battery=1.0, leaf="WaitingForState")
    lines = render_table(recs).splitlines()
    known, waiting = lines[2].split(), lines[3].split()
    assert known[0] == "robot1" and known[4] == "90%"
    assert waiting[0] == "robot2" and waiting[4] == "?" and "100%" not in lines[3]
