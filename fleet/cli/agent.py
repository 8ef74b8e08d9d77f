"""``fleet agent``: robots' agents in their own process, driving robots of a ``fleet sim``."""

from __future__ import annotations

import argparse

from fleet.cli.argtypes import positive_float
from fleet.cli.common import (
    EXIT_INTERRUPTED,
    EXIT_OK,
    SubParsers,
    add_command,
    add_config,
    add_endpoint,
    add_secure,
    add_traffic,
    announce,
    remote_runner,
    robot_list,
)


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet agent`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "agent",
        handle,
        help="run one robot's agent in its own process (robots of a `fleet sim`)",
        description="Run the agent (behavior tree) of one robot whose simulator runs in another process "
        "(`fleet sim`), over Zenoh. Orders come from a `fleet coordinator` or `fleet run`.",
        epilog="example:\n  fleet agent configs/warehouse_patrol.yaml --robot robot3 --endpoint tcp/127.0.0.1:7447\n",
    )
    add_config(p)
    p.add_argument("--robot", required=True, action="append", metavar="NAME", help="robot name (repeatable)")
    p.add_argument(
        "--duration", "-d", type=positive_float, metavar="S", help="simulated seconds (default: forever)"
    )
    add_endpoint(p)
    add_secure(p, "the robot's name")
    add_traffic(p)
    return p


def handle(args: argparse.Namespace) -> int:
    """Run the agents; print one line per robot at the end."""
    robots = [r for item in args.robot for r in robot_list(item)]
    runner = remote_runner(args, robots, coordinator=False, live=False)
    announce(runner, f"agent {', '.join(robots)}")
    report = runner.run()
    for r in report.per_robot:
        print(f"{r.name}: {r.final_state}, {r.distance_m:.1f} m, battery {r.battery_final:.0%}")
    return EXIT_INTERRUPTED if report.interrupted else EXIT_OK
