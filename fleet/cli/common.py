"""What every ``fleet`` command shares: exit codes, common options, the error guard, config
loading and the end-of-run output (summary, report, plot)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, TypeAlias

from rich.console import Console

from fleet.cli.argtypes import positive_int
from fleet.cli.logs import add_log_level
from fleet.errors import BackendError, BusError, ConfigError, ServiceError, TreeError

if TYPE_CHECKING:
    from fleet.bus.session import Secure
    from fleet.config.model import FleetConfig
    from fleet.runtime.report import RunReport
    from fleet.runtime.runner import FleetRunner

logger = logging.getLogger(__name__)

#: ``fleet``'s subparsers (what a command module's ``add_parser`` adds itself to).
SubParsers: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"
#: A command's handler: parsed arguments in, exit code out.
Handler = Callable[[argparse.Namespace], int]

EXIT_OK = 0
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def add_command(sub: SubParsers, name: str, handler: Handler, **kw: Any) -> argparse.ArgumentParser:
    """Add the subcommand ``name`` (``kw``: ``help``, ``description``, ``epilog``); its
    handler is ``args.handler``. Every command takes ``--log-level`` too."""
    p = sub.add_parser(name, formatter_class=argparse.RawDescriptionHelpFormatter, **kw)
    add_log_level(p, default=argparse.SUPPRESS)
    p.set_defaults(handler=handler)
    return p


def standalone_parser(
    prog: str, description: str, epilog: str, add_arguments: Callable[[argparse.ArgumentParser], None]
) -> argparse.ArgumentParser:
    """The parser of a command run on its own (``python -m fleet.cli.status``): the command's
    options plus ``--log-level``."""
    p = argparse.ArgumentParser(
        prog=prog,
        description=description,
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    add_log_level(p)
    return p


def add_config(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, help="fleet config YAML (see docs/config.md)")
    p.add_argument(
        "--robots",
        "-n",
        type=positive_int,
        metavar="N",
        help="number of robots (default: as listed in the config)",
    )


def add_endpoint(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--endpoint",
        metavar="EP",
        help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (default: the config's bus.endpoint)",
    )


def add_secure(p: argparse.ArgumentParser, identity: str | None) -> None:
    """``--secure DIR`` (and ``--identity NAME`` when ``identity`` says what it defaults to):
    open the session on a secured bus (docs/security.md)."""
    p.add_argument(
        "--secure",
        type=Path,
        metavar="DIR",
        help="secured bus: authenticate with the keys of DIR (`fleet keys init`; default: the "
        "config's bus.secure, else an open bus)",
    )
    if identity is not None:
        p.add_argument(
            "--identity",
            metavar="NAME",
            help=f"the identity of DIR to connect as (DIR/NAME.json5; default: {identity})",
        )


def secure_of(
    args: argparse.Namespace, config: FleetConfig | None, default_identity: str | None, hosts: str = ""
) -> Secure | None:
    """The :class:`~fleet.bus.session.Secure` of ``--secure`` (else the config's
    ``bus.secure``) with ``--identity`` or ``default_identity``; ``None`` for an open bus.
    :class:`BusError` if the directory is missing, or if no identity fits (``hosts`` says
    what this process runs, for the message)."""
    from fleet.bus.session import Secure

    keys: Path | None = getattr(args, "secure", None) or (config.secure if config is not None else None)
    if keys is None:
        return None
    if not keys.is_dir():
        raise BusError(
            f"--secure {keys}: no such key directory (make it with `fleet keys init CONFIG {keys}`)"
        )
    identity = getattr(args, "identity", None) or default_identity
    if identity is None:
        raise BusError(
            f"this process runs {hosts}, which no single identity of a secured bus may do: run them as "
            "separate processes (`fleet coordinator`, `fleet agent --robot NAME`) or pass --identity NAME"
        )
    return Secure(keys, identity)


def add_traffic(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--traffic",
        dest="traffic",
        action="store_true",
        default=None,
        help="reservation-based traffic management on the roadmap (default: the config's traffic.enabled, on unless the config says false)",
    )
    g.add_argument(
        "--no-traffic",
        dest="traffic",
        action="store_false",
        help="no traffic management (robots drive their routes unreserved)",
    )


def add_service(p: argparse.ArgumentParser) -> None:
    """``--state`` and ``--api``: the coordinator's durable task book and its HTTP API."""
    p.add_argument(
        "--state",
        type=Path,
        metavar="DIR",
        help="durable task book (SQLite) of the coordinator: a directory that holds one is resumed "
        "(tasks, states, leases, ids, e-stop; with the in-process simulator of `fleet run` also the "
        "robots' poses, batteries and the clock); default: a new one under out/state/",
    )
    p.add_argument(
        "--api",
        metavar="HOST:PORT",
        help="serve the task service's HTTP API and WebSocket here, e.g. 127.0.0.1:8080 (see docs/service.md)",
    )


def state_dir(args: argparse.Namespace, config: FleetConfig) -> Path:
    """``--state``, or a new directory under ``out/state/`` (a run with a coordinator always
    keeps a durable task book)."""
    from fleet.runtime.service_host import default_state_dir

    given: Path | None = getattr(args, "state", None)
    return given if given is not None else default_state_dir(config)


def add_outputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--report", type=Path, metavar="PATH", help="write the JSON report here at the end")
    p.add_argument("--plot", type=Path, metavar="PATH", help="write a PNG of the map and trajectories here")
    p.add_argument(
        "--no-live",
        action="store_true",
        help="no live table; progress instead (a bar on a terminal, a line every 5 s otherwise)",
    )


#: A signal handler as :func:`signal.signal` returns it.
SignalHandler: TypeAlias = "Callable[[int, FrameType | None], Any] | int | signal.Handlers | None"


def _sigterm_as_interrupt() -> tuple[SignalHandler, SignalHandler]:
    """Make SIGTERM and SIGINT raise KeyboardInterrupt (so ``finally`` blocks close the Zenoh
    session). SIGINT too, because a process started in the background of a script inherits
    it ignored, and then ``kill -INT`` would not stop a run. Returns the previous handlers
    (``None`` off the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None, None

    def handler(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, handler), signal.signal(signal.SIGINT, signal.default_int_handler)


def guard(fn: Callable[[], int]) -> int:
    """Run a command: a project error becomes one ``error: <message>`` line on stderr and exit
    code 2; Ctrl-C / SIGTERM exit code 130."""
    old_term, old_int = _sigterm_as_interrupt()
    try:
        return int(fn())
    except (ConfigError, BusError, BackendError, ServiceError, TreeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        logger.warning("interrupted")
        return EXIT_INTERRUPTED
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)
        if old_int is not None:
            signal.signal(signal.SIGINT, old_int)


def load(args: argparse.Namespace) -> FleetConfig:
    """The config named by ``args.config`` with ``args.robots`` robots."""
    from fleet.config.loader import load_config

    return load_config(args.config, robots=args.robots)


def robot_list(text: str) -> list[str]:
    """``"robot1, robot2"`` -> ``["robot1", "robot2"]``."""
    return [r.strip() for r in text.split(",") if r.strip()]


def console() -> Console:
    """A rich console on stdout (colors only on a terminal)."""
    return Console(highlight=False, emoji=False)


def finish(runner: FleetRunner, report: RunReport, args: argparse.Namespace) -> int:
    """Print the summary, write ``--report`` / ``--plot``; the exit code of the run."""
    from fleet.viz.summary import summary_renderable

    out = console()
    # on a terminal rich wraps long lines at word boundaries; in logs a line stays one line
    out.print(summary_renderable(report.to_dict()), soft_wrap=not out.is_terminal)
    if getattr(args, "report", None):
        print(f"report: {report.write_json(args.report)}", flush=True)
    if getattr(args, "plot", None):
        from fleet.viz.plot import plot_run

        title = (
            f"{runner.config.name}: {report.robots} robots, {report.sim_time_s:.0f} s simulated, "
            f"{report.collisions} collisions, {report.laps_completed} laps"
        )
        path = plot_run(
            runner.config, report.trajectories, args.plot, title=title, collisions=runner.collision_points()
        )
        print(f"plot: {path}", flush=True)
    return EXIT_INTERRUPTED if report.interrupted else EXIT_OK


def announce(runner: FleetRunner, what: str) -> None:
    """The first line of a run: the fleet, what runs here, the backend and the bus (open, or
    secured as whom)."""
    from fleet.bus.session import bus_note

    out = Console(file=runner.out, highlight=False, emoji=False, markup=False)
    text = (
        f"fleet: {runner.config.name}, {what}, backend {runner.backend_name}, bus {runner.endpoint} "
        f"({bus_note(runner.secure)})"
    )
    out.print(text, soft_wrap=not out.is_terminal)
    runner.out.flush()


def remote_runner(
    args: argparse.Namespace, agents: list[str], *, coordinator: bool, live: bool | None
) -> FleetRunner:
    """A runner for robots of a `fleet sim` in another process (`fleet coordinator`,
    `fleet agent`): remote backend, as fast as the simulator's clock moves."""
    from fleet.runtime.runner import FleetRunner

    config = load(args)
    if coordinator:
        identity = "coordinator" if not agents else None
        hosts = f"the coordinator and the agents of {', '.join(agents)}"
    else:
        identity = agents[0] if len(agents) == 1 else None
        hosts = f"the agents of {', '.join(agents)}"
    secure = secure_of(args, config, identity, hosts)
    return FleetRunner(
        config,
        duration=args.duration,
        speed=0.0,
        endpoint=args.endpoint,
        backend="remote",
        agents=agents,
        coordinator=coordinator,
        live=live,
        traffic=args.traffic,
        state_dir=state_dir(args, config) if coordinator else None,
        api=getattr(args, "api", None),
        secure=secure,
    )
