"""``fleet sim`` and ``fleet sim-ros``: the simulator served over Zenoh or as namespaced Nav2."""

from __future__ import annotations

import argparse

from fleet.cli.common import EXIT_INTERRUPTED, EXIT_OK, _load
from fleet.errors import BackendError


def _cmd_sim_ros(argv: list[str]) -> int:
    """``fleet sim-ros``: imported lazily so the core never imports rclpy."""
    try:
        from fleet.ros.nav2_server import main as sim_ros_main
    except ImportError as e:
        raise BackendError(
            f"fleet sim-ros needs ROS 2 Jazzy and nav2_msgs ({e}); run `make setup-ros`"
        ) from None
    return int(sim_ros_main(argv) or 0)


def _cmd_sim(args: argparse.Namespace) -> int:
    from fleet.runtime.serve import serve_simulator

    config = _load(args)
    endpoint = args.endpoint or config.endpoint
    print(f"fleet sim: {len(config.robots)} robots of {config.name} on {endpoint}", flush=True)
    result = serve_simulator(config, endpoint=endpoint, speed=args.speed, duration=args.duration)
    if args.plot is not None and result is not None:
        from fleet.viz.plot import plot_run

        sim = result.simulator
        trajectories = {r.name: sim.trajectory(r.namespace) for r in config.robots}
        plot_run(config, trajectories, args.plot, title=f"{config.name}: {len(config.robots)} robots")
        print(f"plot: {args.plot}")
    return EXIT_INTERRUPTED if result is not None and result.interrupted else EXIT_OK
