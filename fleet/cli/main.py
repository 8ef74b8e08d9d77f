"""The ``fleet`` command line. ``fleet --help`` and ``fleet <command> --help`` explain every
option with examples; ``docs/cli.md`` is the reference.

One module per command (``fleet.cli.run``, ``fleet.cli.status``, ...), each with an
``add_parser(subparsers)`` that adds its options and sets its handler; :func:`build_parser`
composes them in the order of :data:`COMMANDS`. A command line naming a command imports only
that command's module (``fleet task list`` never loads the simulator or the config stack);
``fleet --help`` and a command line without a known command import them all. ``--log-level``
(before or after the command; default ``$FLEET_LOG_LEVEL`` or ``warning``) configures
:mod:`logging` for every command (:mod:`fleet.cli.logs`).

Exit codes: 0 success; 2 bad usage, an invalid config or a bus that cannot be opened (one line
``error: <message>`` on stderr, no traceback); 130 interrupted with Ctrl-C (the run is shut
down cleanly and its report and plot are still written)."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

from fleet.cli import sim_ros
from fleet.cli.common import EXIT_ERROR, SubParsers, guard
from fleet.cli.logs import add_log_level, configure_logging, resolve_level

MAIN_EPILOG = """\
examples:
  fleet run configs/warehouse_patrol.yaml
      6 robots patrol with a live table, in real time, until Ctrl-C
  fleet run configs/warehouse_patrol.yaml --robots 12 --speed 0 --duration 600 \\
      --report out/report.json --plot out/trajectories.png
      12 robots, 10 simulated minutes as fast as possible, JSON report and a picture
  fleet status                         # in a second terminal: the live table from the bus
  fleet validate configs/warehouse_patrol.yaml
  fleet --log-level info run configs/warehouse_patrol.yaml --duration 60

  the same fleet in separate processes (each in its own terminal):
  fleet sim configs/warehouse_patrol.yaml --speed 5
  fleet coordinator configs/warehouse_patrol.yaml
  fleet agent configs/warehouse_patrol.yaml --robot robot1     (one per robot)

  a secured bus: identities made once, then --secure on every process (docs/security.md):
  fleet keys init configs/warehouse_patrol.yaml out/keys
  fleet run configs/warehouse_patrol.yaml --secure out/keys

  tasks at runtime (docs/service.md):
  fleet run configs/warehouse_patrol.yaml --api 127.0.0.1:8080 --state out/state/demo
  fleet task submit go_to --target a3_n --wait
  fleet estop --reason "person in aisle 3"; fleet release; fleet resume

exit codes: 0 ok, 2 bad usage / invalid config / bus error, 130 interrupted (Ctrl-C)
"""

#: Each command and the module under ``fleet.cli`` whose ``add_parser`` adds it, in the order
#: ``fleet --help`` lists them (``fleet.cli.task`` adds the task and fleet-control commands).
COMMANDS: dict[str, str] = {
    "run": "run",
    "status": "status",
    "sim": "sim",
    "sim-ros": "sim_ros",
    "agent": "agent",
    "coordinator": "coordinator",
    "validate": "validate",
    "config-schema": "config_schema",
    "loadtest": "loadtest",
    "chaos": "chaos",
    "task": "task",
    "pause": "task",
    "resume": "task",
    "estop": "task",
    "release": "task",
    "keys": "keys",
}

#: Commands whose arguments go, unparsed, to their own parser.
PASSTHROUGH = {"sim-ros": sim_ros.handle}


def _adders(command: str | None) -> list[Callable[[SubParsers], argparse.ArgumentParser]]:
    """The ``add_parser`` of ``command``'s module, or of every module (``None`` or unknown)."""
    modules = [COMMANDS[command]] if command in COMMANDS else list(dict.fromkeys(COMMANDS.values()))
    adders: list[Callable[[SubParsers], argparse.ArgumentParser]] = [
        importlib.import_module(f"fleet.cli.{m}").add_parser for m in modules
    ]
    return adders


def _command_of(argv: list[str]) -> str | None:
    """The command ``argv`` names (its first word after a leading ``--log-level``), if any."""
    _, rest = _leading_log_level(argv)
    return rest[0] if rest and rest[0] in COMMANDS else None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of ``fleet``: with every subcommand, or (``command``) with only
    that command's module (the same parser for that command line, imported faster)."""
    from fleet import __version__

    parser = argparse.ArgumentParser(
        prog="fleet",
        description="Multi-robot fleet orchestrator: behavior-tree robot agents, a coordinator that "
        "assigns patrols, a kinematic simulator and a Zenoh status bus.",
        epilog=MAIN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"fleet {__version__}")
    add_log_level(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in _adders(command):
        add(sub)
    return parser


def _leading_log_level(argv: list[str]) -> tuple[str | None, list[str]]:
    """``--log-level LEVEL`` given before the command, and the arguments from the command on."""
    level = None
    i = 0
    while i < len(argv):
        if argv[i] == "--log-level" and i + 1 < len(argv):
            level, i = argv[i + 1], i + 2
        elif argv[i].startswith("--log-level="):
            level, i = argv[i].partition("=")[2], i + 1
        else:
            break
    return level, argv[i:]


def _passthrough(argv: list[str]) -> int | None:
    """Run a :data:`PASSTHROUGH` command (``--log-level`` stripped from its arguments), or
    ``None`` if ``argv`` names another command."""
    level, rest = _leading_log_level(argv)
    if not rest or rest[0] not in PASSTHROUGH:
        return None
    args, inner = sim_ros.strip_log_level(rest[1:])

    def go() -> int:
        configure_logging(resolve_level(inner or level))
        return PASSTHROUGH[rest[0]](argparse.Namespace(rest=args))

    return guard(go)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``fleet`` command line; returns the exit code (see the module docstring)."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    code = _passthrough(args_list)
    if code is not None:
        return code
    parser = build_parser(_command_of(args_list))
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help()
        return EXIT_ERROR

    def go() -> int:
        configure_logging(resolve_level(args.log_level))
        return int(args.handler(args))

    return guard(go)


def entry() -> None:
    """The ``fleet`` console script and ``python -m fleet.cli``: :func:`main`, then exit at once
    with its code (:func:`fleet.runtime.process_exit.exit_now`: every command has closed its
    Zenoh session, task book and files when :func:`main` returns, and the interpreter's
    finalization took seconds after Ctrl-C)."""
    from fleet.runtime.process_exit import exit_now

    exit_now(main())


if __name__ == "__main__":
    entry()
