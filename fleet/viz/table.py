"""The fleet table: one row per robot from its latest status record, drawn with ``rich``.

Columns, in the order shown: robot, ``x`` / ``y`` (m, ``map`` frame), ``yaw`` (degrees),
``bat`` (battery %; ``?`` before the robot's first state, when its agent knows no battery yet), ``chg`` (charging), ``bt`` (root status), ``leaf`` (active leaf),
``mode``, ``task`` (assignment id), ``laps``, ``prog`` (progress through the lap) and
``flags``: ``STUCK``; the robot's diagnostics that are not OK as ``LEVEL:name``
(``ERROR:localization``, ``WARN:battery``; :mod:`fleet.diagnostics`); ``DEAD`` when the
robot's liveliness token is gone; ``STALE`` when its last record is more than ``silent_s``
simulated seconds older than ``now`` (its bus link is stale).

The layout adapts to the space it is drawn in (:class:`FleetTable` reads the console's width
and height, so a live table follows a resized terminal):

* the essential columns (robot, x, y, bat, mode, task, laps, flags) are always shown; the
  others are added in the order prog, leaf, yaw, bt, chg while they fit the width, and the
  leaf column widens into what is left (up to :data:`LEAF_MAX`);
* one robot per line; when the robots do not fit the height but the width holds two or more
  panes of the essential columns, the robots are split over side-by-side panes;
* when they still do not fit, the robots with flags are shown first and a last line says how
  many robots are not shown (``fleet status --json`` lists every robot).

:func:`render_table` returns the table as plain text (no colors), e.g. for ``fleet status
--once``; without a width it uses every column.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

from rich.console import Console, ConsoleOptions, RenderResult
from rich.table import Table
from rich.text import Text

from fleet.messages import StatusRecord

#: A record this many simulated seconds older than ``now`` is flagged STALE.
SILENT_S = 5.0
#: The width the leaf column gets when it fits, and the widest it grows to (characters).
LEAF_WANTED = 14
LEAF_MAX = 24
#: Width used for the natural (unconstrained) layout when none is given.
NATURAL_WIDTH = 200

_BT_SHORT = {"RUNNING": "RUN", "SUCCESS": "OK", "FAILURE": "FAIL", "INVALID": "-"}
_MODE_STYLE = {"patrol": "cyan", "picking": "magenta", "charging": "green", "recovery": "yellow"}
_PANE_GAP = " │ "

Records = Mapping[str, StatusRecord] | Iterable[StatusRecord]


@dataclass(frozen=True)
class Column:
    """One column: ``width`` in characters (the minimum for ``leaf``); ``rank`` 0 for the
    essential columns, else the order in which optional columns are added when they fit."""

    key: str
    header: str
    width: int
    rank: int
    justify: Literal["left", "right"] = "left"


COLUMNS: tuple[Column, ...] = (
    Column("robot", "robot", 5, 0),
    Column("x", "x", 6, 0, "right"),
    Column("y", "y", 6, 0, "right"),
    Column("yaw", "yaw", 4, 3, "right"),
    Column("bat", "bat", 4, 0, "right"),
    Column("chg", "chg", 3, 5),
    Column("bt", "bt", 4, 4),
    Column("leaf", "leaf", 10, 2),
    Column("mode", "mode", 8, 0),
    Column("task", "task", 8, 0),
    Column("laps", "laps", 4, 0, "right"),
    Column("prog", "prog", 4, 1, "right"),
    Column("flags", "flags", 5, 0),
)


def robot_sort_key(name: str) -> tuple[str, int, str]:
    """Natural order: ``robot2`` before ``robot10``."""
    head = name.rstrip("0123456789")
    tail = name[len(head) :]
    return (head, int(tail) if tail else -1, name)


def as_mapping(records: Records) -> dict[str, StatusRecord]:
    """The records by robot name (a mapping is copied; an iterable is keyed by ``robot``)."""
    if isinstance(records, Mapping):
        return dict(records)
    return {r.robot: r for r in records}


def flags(
    name: str, rec: StatusRecord | None, alive: set[str] | None, now: float | None, silent_s: float
) -> list[str]:
    """The flags of one robot: ``STUCK``, its diagnostics that are not OK, then ``DEAD`` or
    ``STALE`` (see the module docstring)."""
    out = []
    if rec is not None and rec.stuck:
        out.append("STUCK")
    if rec is not None:
        for check, level, _ in rec.diag:
            if check == "motion" and level == 1 and rec.stuck:
                continue  # the same as STUCK
            out.append(f"{LEVEL_NAMES.get(level, str(level))}:{check}")
    if alive is not None and name not in alive:
        out.append("DEAD")
    elif rec is not None and now is not None and now - rec.t > silent_s:
        out.append("STALE")
    return out


#: The names of the diagnostic levels of :class:`fleet.diagnostics.Level`.
LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def summary_line(records: Records, alive: set[str] | None = None, now: float | None = None) -> str:
    """One line: robot count, alive count, time, laps, charging, stuck and dead robots."""
    recs = as_mapping(records)
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


@dataclass(frozen=True)
class Layout:
    """How the table is laid out: the columns (with their widths), the number of side-by-side
    panes, the robots shown (in display order) and how many are left out."""

    columns: tuple[tuple[Column, int], ...]
    panes: int
    shown: tuple[str, ...]
    hidden: int
    hidden_flagged: int


def _line_width(cols: Sequence[tuple[Column, int]]) -> int:
    return sum(w for _, w in cols) + max(0, len(cols) - 1)


def _columns_for(width: int, fixed: Mapping[str, int]) -> tuple[tuple[Column, int], ...]:
    """The columns that fit ``width`` characters: the essential ones, then the optional ones
    by rank (the leaf column at :data:`LEAF_WANTED`, or narrower down to its minimum); the
    leaf column then takes the width left over, up to :data:`LEAF_MAX`. ``fixed`` overrides
    the widths of some columns (robot, task, flags: from the names and ids shown)."""
    widths = {c.key: fixed.get(c.key, c.width) for c in COLUMNS}
    chosen = {c.key for c in COLUMNS if c.rank == 0}
    used = sum(widths[k] for k in chosen) + len(chosen) - 1
    for c in sorted((c for c in COLUMNS if c.rank), key=lambda c: c.rank):
        want = max(c.width, min(LEAF_WANTED, width - used - 1)) if c.key == "leaf" else widths[c.key]
        if used + 1 + want <= width:
            chosen.add(c.key)
            widths[c.key] = want
            used += 1 + want
    if "leaf" in chosen:
        widths["leaf"] = min(LEAF_MAX, widths["leaf"] + max(0, width - used))
    return tuple((c, widths[c.key]) for c in COLUMNS if c.key in chosen)


def plan_layout(
    names: Sequence[str],
    flagged: set[str],
    width: int,
    height: int | None,
    *,
    fixed: Mapping[str, int] | None = None,
) -> Layout:
    """Lay out ``names`` (in natural order) in ``width`` x ``height`` characters (``height``
    ``None``: unlimited). Two lines go to the summary and the header, one to the "not shown"
    line when some robots do not fit. See the module docstring for the rules."""
    fixed = dict(fixed or {})
    essential = _line_width([(c, fixed.get(c.key, c.width)) for c in COLUMNS if c.rank == 0])
    max_panes = max(1, (width + len(_PANE_GAP)) // (essential + len(_PANE_GAP)))
    n = len(names)
    rows = None if height is None else max(1, height - 2)
    panes = 1
    if rows is not None and n > rows:
        panes = min(max_panes, math.ceil(n / rows))
    pane_w = (width - (panes - 1) * len(_PANE_GAP)) // panes
    cols = _columns_for(pane_w, fixed)
    capacity = n if rows is None else panes * rows
    if n <= capacity:
        return Layout(cols, panes, tuple(names), 0, 0)
    capacity = max(1, panes * (rows - 1)) if rows is not None and rows > 1 else 1
    first = [nm for nm in names if nm in flagged][:capacity]
    rest = [nm for nm in names if nm not in flagged][: capacity - len(first)]
    keep = set(first) | set(rest)
    shown = tuple(nm for nm in names if nm in keep)
    hidden = [nm for nm in names if nm not in keep]
    return Layout(cols, panes, shown, len(hidden), sum(1 for nm in hidden if nm in flagged))


def _cut(text: str, width: int) -> str:
    return text if len(text) <= width else text[: max(0, width - 1)] + "~"


def _num(v: float, width: int, digits: int = 1) -> str:
    s = f"{v:.{digits}f}"
    return s if len(s) <= width else f"{v:.0f}"


def _battery_style(b: float) -> str:
    return "bold red" if b < 0.25 else ("yellow" if b < 0.5 else "")


def _cells(
    name: str, rec: StatusRecord | None, fl: list[str], cols: Sequence[tuple[Column, int]]
) -> list[Text]:
    """One row's cells, cut to their column widths."""
    if rec is None:
        values: dict[str, Text] = {k: Text("-", style="dim") for k in ("x", "y", "bat", "mode", "task")}
        values["robot"] = Text(name)
        values["leaf"] = Text("(no status yet)", style="dim")
    else:
        pose = rec.pose
        values = {
            "robot": Text(name),
            "x": Text(_num(pose[0], 6) if pose is not None else "-"),
            "y": Text(_num(pose[1], 6) if pose is not None else "-"),
            "yaw": Text(str(round(math.degrees(pose[2]))) if pose is not None else "-"),
            # before its robot's first state (no pose) an agent knows no battery
            "bat": (
                Text(f"{rec.battery * 100:.0f}%", style=_battery_style(rec.battery))
                if pose is not None
                else Text("?", style="dim")
            ),
            "chg": Text("yes" if rec.charging else ""),
            "bt": Text(_BT_SHORT.get(rec.bt, rec.bt)),
            "leaf": Text(rec.leaf),
            "mode": Text(rec.mode, style=_MODE_STYLE.get(rec.mode, "")),
            "task": Text(rec.task_id or "-"),
            "laps": Text(str(rec.laps)),
            "prog": Text(f"{rec.progress * 100:.0f}%"),
        }
    values["flags"] = Text(" ".join(fl), style="bold red" if fl else "")
    out = []
    for c, w in cols:
        cell = values.get(c.key, Text(""))
        out.append(Text(_cut(cell.plain, w), style=cell.style))
    return out


def _pane(
    names: Sequence[str],
    recs: Mapping[str, StatusRecord],
    fl: Mapping[str, list[str]],
    cols: Sequence[tuple[Column, int]],
) -> Table:
    t = Table(box=None, padding=(0, 1, 0, 0), pad_edge=False, show_edge=False, header_style="bold")
    for c, w in cols:
        t.add_column(c.header, justify=c.justify, width=w, min_width=w, max_width=w, no_wrap=True,
                     overflow="crop")  # fmt: skip
    for n in names:
        style = "dim" if "DEAD" in fl[n] else ""
        t.add_row(*_cells(n, recs.get(n), fl[n], cols), style=style)
    return t


class FleetTable:
    """The fleet table as a rich renderable (see the module docstring).

    ``records``: latest :class:`~fleet.messages.StatusRecord` per robot (a mapping by name or
    an iterable); ``alive``: robots whose liveliness token is held (``None``: unknown, no DEAD
    flags); ``now``: simulated seconds (default: the newest record's ``t``). Robots that are
    alive but never sent a status get a row too. ``height`` caps the lines used (``None``:
    unlimited); the width is the console's.
    """

    def __init__(
        self,
        records: Records,
        alive: set[str] | None = None,
        now: float | None = None,
        *,
        silent_s: float = SILENT_S,
        height: int | None = None,
    ) -> None:
        self.records = as_mapping(records)
        self.alive = alive
        self.now = now if now is not None else max((r.t for r in self.records.values()), default=0.0)
        self.silent_s = silent_s
        self.height = height
        self.names = sorted(set(self.records) | (alive or set()), key=robot_sort_key)
        self.flags = {n: flags(n, self.records.get(n), alive, self.now, silent_s) for n in self.names}

    def layout(self, width: int, height: int | None) -> Layout:
        """The layout for ``width`` x ``height`` characters."""
        fixed = {
            "robot": min(16, max([5, *(len(n) for n in self.names)])),
            "task": min(12, max([4, *(len(r.task_id or "") for r in self.records.values())])),
            "flags": max([5, *(len(" ".join(f)) for f in self.flags.values())]),
        }
        flagged = {n for n, f in self.flags.items() if f}
        return plan_layout(self.names, flagged, width, height, fixed=fixed)

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield Text(summary_line(self.records, self.alive, self.now), style="bold")
        if not self.names:
            yield Text("(no robots seen yet)")
            return
        lay = self.layout(options.max_width, self.height)
        per = math.ceil(len(lay.shown) / lay.panes)
        chunks = [lay.shown[i * per : (i + 1) * per] for i in range(lay.panes)]
        panes = [_pane(c, self.records, self.flags, lay.columns) for c in chunks if c]
        if len(panes) == 1:
            yield panes[0]
        else:
            grid = Table.grid(padding=0)
            cells: list[Table | Text] = []
            for i, p in enumerate(panes):
                if i:
                    grid.add_column(no_wrap=True)
                    cells.append(Text("\n".join([_PANE_GAP] * (per + 1)), style="dim"))
                grid.add_column(no_wrap=True)
                cells.append(p)
            grid.add_row(*cells)
            yield grid
        if lay.hidden:
            more = f" ({lay.hidden_flagged} of them flagged)" if lay.hidden_flagged else ""
            yield Text(
                f"... {lay.hidden} more robots not shown{more}: `fleet status --json` lists all", style="dim"
            )


def render_table(
    records: Records,
    alive: set[str] | None = None,
    now: float | None = None,
    *,
    silent_s: float = SILENT_S,
    width: int | None = None,
    height: int | None = None,
) -> str:
    """The fleet table as plain text (no trailing newline): :class:`FleetTable` drawn ``width``
    characters wide (default: wide enough for every column) and at most ``height`` lines."""
    table = FleetTable(records, alive, now, silent_s=silent_s, height=height)
    buf = io.StringIO()
    console = Console(file=buf, width=width or NATURAL_WIDTH, color_system=None, force_terminal=False,
                      legacy_windows=False, emoji=False, highlight=False)  # fmt: skip
    console.print(table, soft_wrap=False)
    return "\n".join(line.rstrip() for line in buf.getvalue().rstrip("\n").splitlines())
