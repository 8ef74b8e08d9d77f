"""``fleet status``: the live fleet table from the bus alone (no config needed).

Connects as a Zenoh *client* to ``--endpoint`` (default ``tcp/127.0.0.1:7447``, where
``fleet run`` or ``fleet sim`` listens), subscribes to ``fleet/*/status`` and the liveliness
tokens ``fleet/*/alive``, and shows the table of :mod:`fleet.viz.table`.

* default: redraws the table on a TTY (one summary line every few seconds otherwise) until
  Ctrl-C / SIGTERM, or for ``--duration`` wall seconds;
* ``--once``: waits until robots have been seen (every robot holding a token has sent a
  status, or, when no robot holds a token, no new robot for ``--settle`` s), up to ``--wait``
  s, prints one table and exits
  0; exits 1 if no robot was seen;
* ``--json``: prints JSON instead of the table (one object per line in live mode).

Exit codes: 0 ok (also after Ctrl-C), 1 no robot seen (``--once``), 2 the bus cannot be
opened. The session is always closed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any, TextIO

from fleet.bus.session import bus_note, open_session
from fleet.bus.status_bus import StatusBus
from fleet.cli.common import SubParsers, add_command, add_secure, secure_of, standalone_parser
from fleet.cli.logs import configure_logging, resolve_level
from fleet.errors import BusError
from fleet.messages import DEFAULT_ENDPOINT, StatusRecord
from fleet.viz.display import FleetSnapshot, LiveTable
from fleet.viz.table import SILENT_S, render_table, robot_sort_key

EPILOG = """\
examples:
  fleet status                                   # live table of the fleet on tcp/127.0.0.1:7447
  fleet status --once                            # one table, then exit (1 if no robot is seen)
  fleet status --once --json --endpoint tcp/127.0.0.1:7500
"""


DESCRIPTION = (
    "Attach to a running fleet over Zenoh (as a client) and show the fleet table built from the robots' "
    "status messages (fleet/*/status) and liveliness tokens (fleet/*/alive)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``fleet status``."""
    p.add_argument(
        "--endpoint",
        "-e",
        default=DEFAULT_ENDPOINT,
        metavar="EP",
        help=f"Zenoh router (default {DEFAULT_ENDPOINT})",
    )
    p.add_argument(
        "--once", action="store_true", help="print one table when robots have been seen, then exit"
    )
    p.add_argument(
        "--wait", type=float, default=5.0, metavar="S", help="--once: wait up to S s for robots (5)"
    )
    p.add_argument(
        "--settle",
        type=float,
        default=0.5,
        metavar="S",
        help="--once: without liveliness tokens, stop waiting S s after the last new robot "
        "(robots holding a token are waited for, up to --wait)",
    )
    p.add_argument("--json", action="store_true", help="print the latest records as JSON")
    p.add_argument("--duration", type=float, metavar="S", help="live mode: exit after S wall seconds")
    p.add_argument("--interval", type=float, default=0.5, metavar="S", help="live redraw period (0.5 s)")
    p.add_argument(
        "--connect-timeout", type=float, default=2.0, metavar="S", help="wait S s for the router (2)"
    )
    add_secure(p, "observer (read only)")


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet status`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "status",
        handle,
        help="attach to a running fleet and show its live table from the bus",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    add_arguments(p)
    return p


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m fleet.cli.status`` (the options of ``fleet status``)."""
    return standalone_parser("fleet status", DESCRIPTION, EPILOG, add_arguments)


def snapshot(bus: StatusBus) -> dict[str, Any]:
    """``{"t": newest t, "robots": [record dicts by robot], "alive": [...], "malformed": n}``;
    each robot's dict has its diagnostics (``health``: worst level, ``diag``: the checks that
    are not OK), ``battery`` ``None`` while its ``pose`` is (before its robot's first state the
    agent knows no battery) and ``stale``: its record is more than :data:`~fleet.viz.table.SILENT_S` older
    than the newest one."""
    latest = bus.latest()
    names = sorted(latest, key=robot_sort_key)
    t = max((r.t for r in latest.values()), default=None)
    return {
        "t": t,
        "robots": [robot_json(latest[n], t) for n in names],
        "alive": sorted(bus.alive(), key=robot_sort_key),
        "malformed": bus.malformed,
    }


def robot_json(rec: StatusRecord, newest_t: float | None) -> dict[str, Any]:
    """One robot's entry of :func:`snapshot` (``newest_t``: the newest record's ``t``)."""
    d = rec.to_dict()
    d.setdefault("health", 0)
    d.setdefault("diag", [])
    d["stale"] = newest_t is not None and newest_t - rec.t > SILENT_S
    if rec.pose is None:  # before its robot's first state an agent knows no battery
        d["battery"] = None
    return d


def _wait_for_robots(bus: StatusBus, wait_s: float, settle_s: float, stop: threading.Event) -> bool:
    end = time.monotonic() + wait_s
    last_new = time.monotonic()
    known: set[str] = set()
    while not stop.is_set():
        now = time.monotonic()
        seen = set(bus.latest())
        if seen - known:
            known = seen
            last_new = now
        alive = bus.alive()
        if seen and alive <= seen:
            return True
        # robots holding a token are waited for (up to wait_s): with on-change statuses
        # (bus.status_max_period_s) an idle robot speaks only every few seconds
        if seen and not alive and now - last_new >= settle_s:
            return True
        if now >= end:
            break
        stop.wait(0.02)
    return bool(bus.latest())


def status_main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    """Run ``fleet status`` with ``argv`` (without the program name); returns the exit code."""
    args = build_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    configure_logging(resolve_level(args.log_level))
    return handle(args, out)


def handle(args: argparse.Namespace, out: TextIO | None = None) -> int:
    """``fleet status`` with parsed arguments (see the module docstring for the exit codes)."""
    out = out or sys.stdout
    stop = threading.Event()
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        try:
            secure = secure_of(args, None, "observer")
            session = open_session(
                args.endpoint, "client", connect_timeout_s=args.connect_timeout, secure=secure
            )
        except BusError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        bus = StatusBus(session, max_events=0)
        try:
            bus.watch_alive()
            bus.subscribe_statuses()
            if args.once:
                return _once(bus, args, out, stop)
            return _live(bus, args, out, stop)
        except KeyboardInterrupt:
            return 0
        finally:
            bus.shutdown()
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def _once(bus: StatusBus, args: argparse.Namespace, out: TextIO, stop: threading.Event) -> int:
    if not _wait_for_robots(bus, args.wait, args.settle, stop):
        print(
            f"no robot status seen on {args.endpoint} within {args.wait:g} s "
            "(is a fleet running there? start one with `fleet run CONFIG`)",
            file=sys.stderr,
        )
        return 1
    if args.json:
        print(json.dumps(snapshot(bus)), file=out, flush=True)
    else:
        width = shutil.get_terminal_size().columns if out.isatty() else None
        print(render_table(bus.latest(), bus.alive(), width=width), file=out, flush=True)
    return 0


def _live(bus: StatusBus, args: argparse.Namespace, out: TextIO, stop: threading.Event) -> int:
    end = None if args.duration is None else time.monotonic() + args.duration
    table = None if args.json else LiveTable(out, interval_s=args.interval)
    if table is not None and not table.tty:
        note = bus_note(secure_of(args, None, "observer"))
        print(f"fleet status: watching {args.endpoint} ({note}; Ctrl-C to stop)", file=out, flush=True)
    t0 = time.monotonic()
    next_line = t0
    try:
        while not stop.is_set() and (end is None or time.monotonic() < end):
            if table is None:
                print(json.dumps(snapshot(bus)), file=out, flush=True)
            elif time.monotonic() >= next_line:
                table.show(_snapshot(bus, time.monotonic() - t0))
                next_line = time.monotonic() + table.interval_s
            stop.wait(args.interval)
    finally:
        if table is not None:
            table.close(_snapshot(bus, time.monotonic() - t0))
    return 0


def _snapshot(bus: StatusBus, wall_s: float) -> FleetSnapshot:
    latest = bus.latest()
    return FleetSnapshot(
        sim_time_s=max((r.t for r in latest.values()), default=0.0),
        wall_s=wall_s,
        records=[latest[n] for n in sorted(latest, key=robot_sort_key)],
        alive=bus.alive(),
    )


if __name__ == "__main__":
    sys.exit(status_main())
