"""The ``fleet`` command line. ``fleet --help`` and ``fleet <command> --help`` explain every
option with examples; ``docs/cli.md`` is the reference.

Exit codes: 0 success; 2 bad usage, an invalid config or a bus that cannot be opened (one line
``error: <message>`` on stderr, no traceback); 130 interrupted with Ctrl-C (the run is shut
down cleanly and its report and plot are still written).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fleet.argtypes import non_negative_float as _non_negative_float
from fleet.argtypes import positive_float as _positive_float
from fleet.argtypes import positive_int as _positive_int
from fleet.errors import BackendError, BusError, ConfigError

EXIT_OK = 0
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130

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


def _add_config(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, help="fleet config YAML (see docs/config.md)")
    p.add_argument(
        "--robots",
        "-n",
        type=_positive_int,
        metavar="N",
        help="number of robots (default: as listed in the config)",
    )


def _add_endpoint(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--endpoint",
        metavar="EP",
        help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (default: the config's bus.endpoint)",
    )


def _add_traffic(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--traffic",
        dest="traffic",
        action="store_true",
        default=None,
        help="reservation-based traffic management on the roadmap (default: the config's traffic.enabled)",
    )
    g.add_argument("--no-traffic", dest="traffic", action="store_false", help="no traffic management")


def _add_outputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--report", type=Path, metavar="PATH", help="write the JSON report here at the end")
    p.add_argument("--plot", type=Path, metavar="PATH", help="write a PNG of the map and trajectories here")
    p.add_argument(
        "--no-live", action="store_true", help="no live table; print a progress line every 5 s instead"
    )


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
        "the robots' status messages alone. Options are those of fleet.status_view (see --help).",
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
    from fleet.loadtest import add_loadtest_parser

    add_loadtest_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``fleet`` command line; returns the exit code (see the module docstring)."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] == "status":
        from fleet.status_view import status_main

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
    }
    return _guard(lambda: handlers[args.command](args))


def _cmd_sim_ros(argv: list[str]) -> int:
    """``fleet sim-ros``: imported lazily so the core never imports rclpy."""
    try:
        from fleet.ros.nav2_server import main as sim_ros_main
    except ImportError as e:
        raise BackendError(
            f"fleet sim-ros needs ROS 2 Jazzy and nav2_msgs ({e}); run `make setup-ros`"
        ) from None
    return int(sim_ros_main(argv) or 0)


def _sigterm_as_interrupt() -> Any:
    """Make SIGTERM raise KeyboardInterrupt (so ``finally`` blocks close the Zenoh session);
    returns the previous handler (None off the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, handler)


def _guard(fn: Any) -> int:
    old = _sigterm_as_interrupt()
    try:
        return int(fn())
    except (ConfigError, BusError, BackendError) as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def _load(args: argparse.Namespace) -> Any:
    from fleet.config import load_config

    return load_config(args.config, robots=args.robots)


def _robot_list(text: str) -> list[str]:
    return [r.strip() for r in text.split(",") if r.strip()]


def _finish(runner: Any, report: Any, args: argparse.Namespace) -> int:
    print(report.summary(), flush=True)
    if getattr(args, "report", None):
        path = report.write_json(args.report)
        print(f"report: {path}")
    if getattr(args, "plot", None):
        from fleet.plot import plot_run

        title = (
            f"{runner.config.name}: {report.robots} robots, {report.sim_time_s:.0f} s simulated, "
            f"{report.collisions} collisions, {report.laps_completed} laps"
        )
        path = plot_run(
            runner.config, report.trajectories, args.plot, title=title, collisions=runner.collision_points()
        )
        print(f"plot: {path}")
    return EXIT_INTERRUPTED if report.interrupted else EXIT_OK


def _cmd_run(args: argparse.Namespace) -> int:
    from fleet.runner import FleetRunner

    config = _load(args)
    agents: str | list[str] = "all" if args.agents == "all" else _robot_list(args.agents)
    runner = FleetRunner(
        config,
        duration=args.duration,
        speed=args.speed,
        endpoint=args.endpoint,
        backend=args.backend,
        agents=agents,
        coordinator=not args.no_coordinator,
        live=False if args.no_live else None,
        tree_kind=args.tree,
        traffic=args.traffic,
    )
    _announce(runner, f"{len(runner.agent_names)} agents" + ("" if args.no_coordinator else " + coordinator"))
    return _finish(runner, runner.run(), args)


def _remote_runner(
    args: argparse.Namespace, agents: list[str], *, coordinator: bool, live: bool | None
) -> Any:
    """A runner for robots of a `fleet sim` in another process (`fleet coordinator`,
    `fleet agent`): remote backend, as fast as the simulator's clock moves."""
    from fleet.runner import FleetRunner

    return FleetRunner(
        _load(args),
        duration=args.duration,
        speed=0.0,
        endpoint=args.endpoint,
        backend="remote",
        agents=agents,
        coordinator=coordinator,
        live=live,
        traffic=args.traffic,
    )


def _cmd_coordinator(args: argparse.Namespace) -> int:
    runner = _remote_runner(
        args, _robot_list(args.agents), coordinator=True, live=False if args.no_live else None
    )
    _announce(
        runner, "coordinator" + (f" + agents {', '.join(runner.agent_names)}" if runner.agent_names else "")
    )
    return _finish(runner, runner.run(), args)


def _cmd_agent(args: argparse.Namespace) -> int:
    robots = [r for item in args.robot for r in _robot_list(item)]
    runner = _remote_runner(args, robots, coordinator=False, live=False)
    _announce(runner, f"agent {', '.join(robots)}")
    report = runner.run()
    for r in report.per_robot:
        print(f"{r.name}: {r.final_state}, {r.distance_m:.1f} m, battery {r.battery_final:.0%}")
    return EXIT_INTERRUPTED if report.interrupted else EXIT_OK


def _cmd_sim(args: argparse.Namespace) -> int:
    from fleet.nav_bridge import serve_simulator

    config = _load(args)
    endpoint = args.endpoint or config.endpoint
    print(f"fleet sim: {len(config.robots)} robots of {config.name} on {endpoint}", flush=True)
    result = serve_simulator(config, endpoint=endpoint, speed=args.speed, duration=args.duration)
    if args.plot is not None and result is not None:
        from fleet.plot import plot_run

        sim = result.simulator
        trajectories = {r.name: sim.trajectory(r.namespace) for r in config.robots}
        plot_run(config, trajectories, args.plot, title=f"{config.name}: {len(config.robots)} robots")
        print(f"plot: {args.plot}")
    return EXIT_INTERRUPTED if result is not None and result.interrupted else EXIT_OK


def _cmd_validate(args: argparse.Namespace) -> int:
    config = _load(args)
    xmin, xmax, ymin, ymax = config.grid.extent
    print(f"{config.path}: ok")
    print(f"  name:        {config.name}")
    print(
        f"  map:         {config.map_path} ({xmax - xmin:g} x {ymax - ymin:g} m, {config.grid.resolution:g} m/cell)"
    )
    print(f"  roadmap:     {len(config.roadmap)} nodes, {len(config.roadmap.edges)} edges")
    print(
        f"  robots:      {len(config.robots)} ({', '.join(r.name for r in config.robots[:8])}"
        f"{', ...' if len(config.robots) > 8 else ''})"
    )
    print(f"  routes:      {len(config.routes)} ({', '.join(r.name for r in config.routes)})")
    print(f"  tasks:       {len(config.tasks)}")
    print(f"  chargers:    {len(config.chargers)}   stations: {len(config.stations)}")
    print(f"  sim:         step {config.sim.step_s:g} s, agents tick at {config.tick_hz:g} Hz")
    print(f"  bus:         {config.endpoint}")
    return EXIT_OK


def _announce(runner: Any, what: str) -> None:
    print(
        f"fleet: {runner.config.name}, {what}, backend {runner.backend_name}, bus {runner.endpoint}",
        file=runner.out,
        flush=True,
    )


if __name__ == "__main__":
    sys.exit(main())
