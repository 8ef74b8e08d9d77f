"""What a user watches while a fleet runs: the live table and progress, drawn with ``rich``.

A running loop (the runner, ``fleet status``, ``fleet sim``, a load test) hands a
:class:`FleetSnapshot` to a :class:`FleetDisplay` every :attr:`FleetDisplay.interval_s` wall
seconds and closes it at the end. The displays:

* :class:`LiveTable`: on a terminal, the fleet table of :mod:`fleet.viz.table` redrawn in
  place (``rich.live.Live``), fitted to the terminal's width and height at every redraw;
  otherwise one summary line every :data:`LINE_EVERY_S` wall seconds.
* :class:`ProgressDisplay`: on a terminal, one progress bar (simulated time out of the
  duration, real-time factor, laps, ...); otherwise one plain line every
  :data:`LINE_EVERY_S` wall seconds, for CI logs.
* :class:`NullDisplay`: shows nothing.

:func:`default_display` picks the live table or the progress display for an output stream.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, TextIO

from rich.console import Console
from rich.live import Live
from rich.progress import BarColumn, Progress, SpinnerColumn, TaskID, TextColumn

from fleet.messages import StatusRecord
from fleet.viz.table import FleetTable, summary_line

#: Plain (not a terminal) progress and summary lines are written this often (wall seconds).
LINE_EVERY_S = 5.0
#: A terminal display is redrawn this often (wall seconds).
REDRAW_EVERY_S = 0.25


@dataclass(frozen=True)
class FleetSnapshot:
    """The state of a run at one moment, for a display.

    ``sim_time_s``: simulated seconds; ``wall_s``: wall seconds since the run started;
    ``records``: the latest status record of each robot known; ``alive``: robots holding a
    liveliness token (``None``: not watched); ``duration_s``: the run's simulated length
    (``None``: until stopped). The counts default to what the records say (``robots``: their
    number, ``laps``: their sum, ``charging``: robots in mode ``charging``); ``collisions``,
    ``deadlocks``, ``states`` (robots per state), ``real_time_factor`` and ``note`` (free text)
    are shown when given. ``label`` names the run in progress lines (e.g. ``loadtest``).
    ``clock_s``: the fleet's simulated clock when it is not this run's (a coordinator or agent
    of a simulator in another process, which may have joined, or been restarted into, a fleet
    already running); progress lines then show it as ``t`` (``None``: ``sim_time_s``).
    """

    sim_time_s: float
    wall_s: float
    records: Sequence[StatusRecord] = ()
    alive: set[str] | None = None
    duration_s: float | None = None
    robots: int | None = None
    laps: int | None = None
    charging: int | None = None
    collisions: int | None = None
    deadlocks: int | None = None
    states: Mapping[str, int] | None = None
    real_time_factor: float | None = None
    note: str = ""
    label: str = ""
    clock_s: float | None = None

    def clock(self) -> float:
        """The fleet's clock (simulated s): ``clock_s``, else ``sim_time_s``."""
        return self.sim_time_s if self.clock_s is None else self.clock_s

    def counts(self) -> str:
        """``6 robots, 3 laps, 1 charging`` plus the optional counts that are set. Robots, laps
        and charging robots are shown when given or when there are records (charging not
        with ``states``, which already tells it)."""
        recs = self.records
        parts = []
        if self.robots is not None or recs:
            parts.append(f"{self.robots if self.robots is not None else len(recs)} robots")
        if self.laps is not None or recs:
            parts.append(f"{self.laps if self.laps is not None else sum(r.laps for r in recs)} laps")
        if self.states is None and (self.charging is not None or recs):
            charging = (
                self.charging if self.charging is not None else sum(1 for r in recs if r.mode == "charging")
            )
            parts.append(f"{charging} charging")
        if self.collisions is not None:
            parts.append(f"{self.collisions} collisions")
        if self.deadlocks is not None:
            parts.append(f"{self.deadlocks} deadlocks")
        text = ", ".join(parts)
        extra = []
        if self.states:
            extra.append(", ".join(f"{s} {n}" for s, n in self.states.items() if n))
        if self.note:
            extra.append(self.note)
        return "; ".join([text, *extra] if text else extra)


def progress_line(snap: FleetSnapshot) -> str:
    """One plain progress line: ``[t=  12.0 s sim,    5.0 s wall] 6 robots, 3 laps, 1 charging``
    (with the label and the real-time factor when set); ``t`` is the fleet's clock
    (``clock_s``) when given, so a restarted coordinator goes on from the fleet's time."""
    head = f"{snap.label} " if snap.label else ""
    rtf = f", {snap.real_time_factor:5.2f}x real time" if snap.real_time_factor is not None else ""
    return f"[{head}t={snap.clock():7.1f} s sim, {snap.wall_s:6.1f} s wall{rtf}] {snap.counts()}"


class FleetDisplay(Protocol):
    """Something that shows a running fleet; see the module docstring."""

    @property
    def interval_s(self) -> float:
        """How often (wall seconds) the display wants a new snapshot."""
        ...

    def show(self, snap: FleetSnapshot) -> None:
        """Show ``snap`` now."""
        ...

    def close(self, final: FleetSnapshot | None = None) -> None:
        """End the display, drawing ``final`` first if given and the display redraws in place
        (what was drawn last stays on screen)."""
        ...


def _console(out: TextIO, tty: bool | None) -> Console:
    return Console(file=out, force_terminal=tty, highlight=False, emoji=False, soft_wrap=False)


def _screen(
    out: TextIO, tty: bool | None, console: Console | None, interval_s: float, line_every_s: float
) -> tuple[Console, bool, float]:
    """A display's console, whether it redraws in place (a terminal), and how often it draws
    (``interval_s`` on a terminal, ``line_every_s`` otherwise)."""
    con = console or _console(out, tty)
    is_tty = con.is_terminal if tty is None else tty
    return con, is_tty, interval_s if is_tty else line_every_s


class NullDisplay:
    """Shows nothing."""

    interval_s = 3600.0

    def show(self, snap: FleetSnapshot) -> None:
        return None

    def close(self, final: FleetSnapshot | None = None) -> None:
        return None


class LiveTable:
    """The fleet table redrawn in place on a terminal, summary lines otherwise.

    ``out``: the stream (a terminal or not: ``tty`` defaults to ``out.isatty()``);
    ``interval_s``: redraw period on a terminal; ``line_every_s``: the period of the
    summary lines otherwise; ``console``: draw on this rich console instead (its width and
    height are used, e.g. a fixed-size console in tests). While the table is live, what
    other code writes to stdout / stderr (log messages) is shown above it.
    """

    def __init__(
        self,
        out: TextIO,
        *,
        interval_s: float = REDRAW_EVERY_S,
        line_every_s: float = LINE_EVERY_S,
        tty: bool | None = None,
        console: Console | None = None,
    ) -> None:
        self.console, self.tty, self._every = _screen(out, tty, console, interval_s, line_every_s)
        self.out = out
        self._live: Live | None = None
        self.draws = 0

    @property
    def interval_s(self) -> float:
        return self._every

    def show(self, snap: FleetSnapshot) -> None:
        self.update(snap.records, snap.alive, snap.clock())

    def update(self, records: Sequence[StatusRecord], alive: set[str] | None, now: float | None) -> None:
        """Redraw the table (terminal) or write one summary line (not a terminal)."""
        self.draws += 1
        if not self.tty:
            self.out.write(summary_line(records, alive, now) + "\n")
            self.out.flush()
            return
        table = FleetTable(records, alive, now, height=max(3, self.console.size.height - 1))
        if self._live is None:
            redirect = self.out is self.console.file and self.console.file.isatty()
            self._live = Live(
                table,
                console=self.console,
                auto_refresh=False,
                redirect_stdout=redirect,
                redirect_stderr=redirect,
            )
            self._live.start(refresh=True)
        else:
            self._live.update(table, refresh=True)

    def close(self, final: FleetSnapshot | None = None) -> None:
        """Draw ``final`` (a last summary line when not a terminal) and stop redrawing."""
        if final is not None and (self._live is not None or not self.tty):
            self.show(final)
        if self._live is not None:
            self._live.stop()
            self._live = None


class ProgressDisplay:
    """Progress of a run: a rich progress bar on a terminal (simulated time out of the
    duration, or a spinner without one, plus the counts), plain :func:`progress_line` lines
    every ``line_every_s`` wall seconds otherwise. ``tty`` defaults to ``out.isatty()``."""

    def __init__(
        self,
        out: TextIO,
        *,
        interval_s: float = REDRAW_EVERY_S,
        line_every_s: float = LINE_EVERY_S,
        tty: bool | None = None,
        console: Console | None = None,
    ) -> None:
        self.console, self.tty, self._every = _screen(out, tty, console, interval_s, line_every_s)
        self.out = out
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self.draws = 0

    @property
    def interval_s(self) -> float:
        return self._every

    def show(self, snap: FleetSnapshot) -> None:
        self.draws += 1
        if not self.tty:
            self.out.write(progress_line(snap) + "\n")
            self.out.flush()
            return
        rtf = f"{snap.real_time_factor:.1f}x" if snap.real_time_factor is not None else ""
        sim, counts = f"{snap.clock():.1f}", snap.counts()
        if self._progress is None:
            self._progress = Progress(
                SpinnerColumn() if snap.duration_s is None else BarColumn(bar_width=24),
                TextColumn("[bold]{task.description}[/] t={task.fields[sim]} s"),
                TextColumn("{task.fields[rtf]}"),
                TextColumn("{task.fields[counts]}"),
                console=self.console,
                auto_refresh=False,
                redirect_stdout=False,
                redirect_stderr=False,
            )
            self._progress.start()
            self._task = self._progress.add_task(
                snap.label or "fleet", total=snap.duration_s, sim=sim, rtf=rtf, counts=counts
            )
        assert self._task is not None
        self._progress.update(self._task, completed=snap.sim_time_s, sim=sim, rtf=rtf, counts=counts)
        self._progress.refresh()

    def close(self, final: FleetSnapshot | None = None) -> None:
        if final is not None and self._progress is not None:
            self.show(final)
        if self._progress is not None:
            self._progress.stop()
            self._progress = None


def default_display(out: TextIO, live: bool | None = None) -> FleetDisplay:
    """The live table when ``live`` (default: when ``out`` is a terminal), else the progress
    display (a bar on a terminal, plain lines otherwise)."""
    tty = out.isatty()
    if live if live is not None else tty:
        return LiveTable(out)
    return ProgressDisplay(out)
