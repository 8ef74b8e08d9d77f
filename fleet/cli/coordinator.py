"""``fleet coordinator``: the coordinator in its own process, against robots on the bus."""

from __future__ import annotations

import argparse

from fleet.cli.argtypes import positive_float
from fleet.cli.common import (
    SubParsers,
    add_command,
    add_config,
    add_endpoint,
    add_outputs,
    add_secure,
    add_service,
    add_traffic,
    announce,
    finish,
    remote_runner,
    robot_list,
)


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet coordinator`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "coordinator",
        handle,
        help="run the coordinator in its own process (robots of a `fleet sim`)",
        description="Run the coordinator against robots on the bus: assign patrols, reassign when a robot "
        "dies, is stuck or charges. Can also host some robots' agents (--agents).",
        epilog="example:\n  fleet coordinator configs/warehouse_patrol.yaml --agents robot1,robot2 "
        "--report out/coord.json\n",
    )
    add_config(p)
    p.add_argument(
        "--duration", "-d", type=positive_float, metavar="S", help="simulated seconds (default: forever)"
    )
    p.add_argument(
        "--agents", default="", metavar="LIST", help="robots whose agents also run here (robot1,robot2)"
    )
    add_endpoint(p)
    add_secure(p, "coordinator")
    add_outputs(p)
    add_traffic(p)
    add_service(p)
    return p


def handle(args: argparse.Namespace) -> int:
    """Run the coordinator (and ``--agents``); print the summary; write the report and plot."""
    runner = remote_runner(
        args, robot_list(args.agents), coordinator=True, live=False if args.no_live else None
    )
    hosted = f" + agents {', '.join(runner.agent_names)}" if runner.agent_names else ""
    announce(runner, "coordinator" + hosted)
    return finish(runner, runner.run(), args)
