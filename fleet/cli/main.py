"""The ``fleet`` command line. ``fleet --help`` and ``fleet <command> --help`` explain every
option with examples; ``docs/cli.md`` is the reference.

Exit codes: 0 success; 2 bad usage, an invalid config or a bus that cannot be opened (one line
``error: <message>`` on stderr, no traceback); 130 interrupted with Ctrl-C (the run is shut
down cleanly and its report and plot are still written)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from fleet.cli.argtypes import non_negative_float as _non_negative_float
from fleet.cli.argtypes import positive_float as _positive_float
from fleet.cli.common import EXIT_ERROR, _add_config, _add_endpoint, _add_outputs, _add_traffic, _guard
from fleet.cli.config_schema import add_config_schema_parser, cmd_config_schema
from fleet.cli.run import _cmd_agent, _cmd_coordinator, _cmd_run
from fleet.cli.sim import _cmd_sim, _cmd_sim_ros
from fleet.cli.validate import _cmd_validate

MAIN_EPILOG = """\
examples:
  fleet run configs/warehouse_patrol.yaml
      6 robots patrol with a live table, in real time, until Ctrl-C
  fleet run configs/warehouse_patrol.yaml --robots 12 --speed 0 --duration 600 \\
      --report out/report.json --plot out/trajectories.png
      12 robots, 10 simulated minutes as fast as possible, JSON report and a picture
  fleet status                         # in a second terminal: the live table from the bus
  fleet validate configs/warehouse_patrol.yaml

  the same fleet in separate processes (each in its own terminal):
  fleet sim configs/warehouse_patrol.yaml --speed 5
  fleet coordinator configs/warehouse_patrol.yaml
  fleet agent configs/warehouse_patrol.yaml --robot robot1     (one per robot)

exit codes: 0 ok, 2 bad usage / invalid config / bus error, 130 interrupted (Ctrl-C)
"""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``fleet`` (all subcommands)."""
    parser = argparse.ArgumentParser(
        prog="fleet",
        description="Multi-robot fleet orchestrator: behavior-tree robot agents, a coordinator that "
        "assigns patrols, a kinematic simulator and a Zenoh status bus.",
        epilog=MAIN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from fleet import __version__

    parser.add_argument("--version", action="version", version=f"fleet {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = sub.add_parser(
        "run",
        help="run a fleet: simulator + agents + coordinator in one process",
        description="Start a Zenoh router on the endpoint, the simulator with N robots, one agent (behavior "
        "tree) per robot and the coordinator; show a live table; print a summary at the end.",
        epilog="""\
examples:
  fleet run configs/warehouse_patrol.yaml                    # real time until Ctrl-C
  fleet run configs/warehouse_patrol.yaml --duration 300 --speed 10
  fleet run configs/warehouse_patrol_30.yaml --speed 0 --duration 600 --report r.json --plot r.png
  fleet run configs/warehouse_patrol.yaml --agents robot1,robot2 --backend remote
      (robots of a `fleet sim` in another process; the other robots run `fleet agent`)
  fleet run configs/warehouse_picking.yaml --tree picking --speed 0 --duration 300
      (picking trees: the coordinator hands out the config's tasks instead of its routes)

--duration and --speed are in simulated seconds; --speed 0 runs as fast as the CPU allows.
""",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_config(run)
    run.add_argument(
        "--duration",
        "-d",
        type=_positive_float,
        metavar="S",
        help="simulated seconds to run (default: until Ctrl-C)",
    )
    run.add_argument(
        "--speed",
        "-s",
        type=_non_negative_float,
        default=1.0,
        metavar="X",
        help="multiple of real time; 0 = as fast as possible (default 1)",
    )
    _add_endpoint(run)
    _add_outputs(run)
    _add_traffic(run)
    run.add_argument(
        "--backend", default="sim", metavar="NAME", help="navigation backend (default sim; see docs/cli.md)"
    )
    run.add_argument(
        "--agents",
        default="all",
        metavar="LIST",
        help="robots whose agents run here: all (default) or robot1,robot2",
    )
    run.add_argument(
        "--no-coordinator", action="store_true", help="do not run the coordinator in this process"
    )
    run.add_argument(
        "--tree",
        choices=("patrol", "picking"),
        default="patrol",
        help="behavior tree of every robot: patrol (the coordinator assigns the config's routes; "
        "default) or picking (it assigns the config's tasks, each done once; not with --traffic)",
    )

    status = sub.add_parser(
        "status",
        help="attach to a running fleet and show its live table from the bus",
        description="Connect to the Zenoh endpoint of a running fleet and print the fleet table built from "
        "the robots' status messages alone. Options are those of fleet.cli.status (see --help).",
        add_help=False,
    )
    status.add_argument("rest", nargs=argparse.REMAINDER)

    simros = sub.add_parser(
        "sim-ros",
        help="serve the simulator as namespaced Nav2 over ROS 2 (needs make setup-ros)",
        description="Serve every robot of the config as namespaced Nav2 over ROS 2 Jazzy: the Nav2 "
        "action servers, lifecycle get_state, amcl_pose, odom and the costmap services, so "
        "nav2_simple_commander scripts and `fleet run --backend ros` drive the simulator. "
        "Options are those of fleet.ros.nav2_server (see `fleet sim-ros --help`).",
        epilog="example:\n  fleet sim-ros configs/warehouse_patrol.yaml --speed 10\n"
        "  fleet run configs/warehouse_patrol.yaml --backend ros    # in a second terminal\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    simros.add_argument("rest", nargs=argparse.REMAINDER)

    agent = sub.add_parser(
        "agent",
        help="run one robot's agent in its own process (robots of a `fleet sim`)",
        description="Run the agent (behavior tree) of one robot whose simulator runs in another process "
        "(`fleet sim`), over Zenoh. Orders come from a `fleet coordinator` or `fleet run`.",
        epilog="example:\n  fleet agent configs/warehouse_patrol.yaml --robot robot3 --endpoint tcp/127.0.0.1:7447\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_config(agent)
    agent.add_argument(
        "--robot", required=True, action="append", metavar="NAME", help="robot name (repeatable)"
    )
    agent.add_argument(
        "--duration", "-d", type=_positive_float, metavar="S", help="simulated seconds (default: forever)"
    )
    _add_endpoint(agent)
    _add_traffic(agent)

    coord = sub.add_parser(
        "coordinator",
        help="run the coordinator in its own process (robots of a `fleet sim`)",
        description="Run the coordinator against robots on the bus: assign patrols, reassign when a robot "
        "dies, is stuck or charges. Can also host some robots' agents (--agents).",
        epilog="example:\n  fleet coordinator configs/warehouse_patrol.yaml --agents robot1,robot2 "
        "--report out/coord.json\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_config(coord)
    coord.add_argument(
        "--duration", "-d", type=_positive_float, metavar="S", help="simulated seconds (default: forever)"
    )
    coord.add_argument(
        "--agents", default="", metavar="LIST", help="robots whose agents also run here (robot1,robot2)"
    )
    _add_endpoint(coord)
    _add_outputs(coord)
    _add_traffic(coord)

    simp = sub.add_parser(
        "sim",
        help="serve the simulator over Zenoh for agents in other processes",
        description="Run the kinematic simulator with the config's robots and serve their navigation "
        "actions and the simulated clock over Zenoh (listening on the endpoint).",
        epilog="example:\n  fleet sim configs/warehouse_patrol.yaml --speed 5 --duration 600\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_config(simp)
    simp.add_argument(
        "--speed",
        "-s",
        type=_non_negative_float,
        default=1.0,
        metavar="X",
        help="multiple of real time (default 1)",
    )
    simp.add_argument(
        "--duration", "-d", type=_positive_float, metavar="S", help="simulated seconds (default: forever)"
    )
    _add_endpoint(simp)
    simp.add_argument("--plot", type=Path, metavar="PATH", help="write a PNG of the trajectories at the end")

    val = sub.add_parser(
        "validate",
        help="load a config, report the first problem or print a summary",
        description="Load and validate a fleet config. Prints a summary, or one line naming the file, the "
        "field and the reason, and exits 2.",
        epilog="example:\n  fleet validate configs/warehouse_patrol.yaml --robots 30\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_config(val)
    from fleet.cli.loadtest import add_loadtest_parser

    add_loadtest_parser(sub)
    add_config_schema_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``fleet`` command line; returns the exit code (see the module docstring)."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] == "status":
        from fleet.cli.status import status_main

        return _guard(lambda: int(status_main(args_list[1:]) or 0))
    if args_list and args_list[0] == "sim-ros":
        return _guard(lambda: _cmd_sim_ros(args_list[1:]))
    parser = build_parser()
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help()
        return EXIT_ERROR
    handlers = {
        "run": _cmd_run,
        "agent": _cmd_agent,
        "coordinator": _cmd_coordinator,
        "sim": _cmd_sim,
        "validate": _cmd_validate,
        "loadtest": lambda a: a.loadtest_handler(a),
        "config-schema": cmd_config_schema,
    }
    return _guard(lambda: handlers[args.command](args))


if __name__ == "__main__":
    sys.exit(main())
