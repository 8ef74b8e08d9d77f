"""``fleet run``, ``fleet coordinator`` and ``fleet agent``: a fleet, or a part of one, in this process."""

from __future__ import annotations

import argparse
from typing import Any

from fleet.cli.common import EXIT_INTERRUPTED, EXIT_OK, _announce, _finish, _load, _robot_list


def _cmd_run(args: argparse.Namespace) -> int:
    from fleet.runtime.runner import FleetRunner

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
    from fleet.runtime.runner import FleetRunner

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
