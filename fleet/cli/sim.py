"""``fleet sim``: the simulator served over Zenoh for agents in other processes."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fleet.cli.argtypes import non_negative_float, positive_float
from fleet.cli.common import (
    EXIT_INTERRUPTED,
    EXIT_OK,
    SubParsers,
    add_command,
    add_config,
    add_endpoint,
    add_secure,
    load,
    secure_of,
)

#: Plain progress lines of ``fleet sim`` (not a terminal) come this often (wall seconds).
PROGRESS_EVERY_S = 10.0


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet sim`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "sim",
        handle,
        help="serve the simulator over Zenoh for agents in other processes",
        description="Run the kinematic simulator with the config's robots and serve their navigation "
        "actions and the simulated clock over Zenoh (listening on the endpoint).",
        epilog="example:\n  fleet sim configs/warehouse_patrol.yaml --speed 5 --duration 600\n"
        "  fleet sim configs/warehouse_patrol.yaml --state out/sim-state   # restartable\n",
    )
    add_config(p)
    p.add_argument(
        "--speed",
        "-s",
        type=non_negative_float,
        default=1.0,
        metavar="X",
        help="multiple of real time (default 1)",
    )
    p.add_argument(
        "--duration", "-d", type=positive_float, metavar="S", help="simulated seconds (default: forever)"
    )
    add_endpoint(p)
    add_secure(p, None)
    p.add_argument("--plot", type=Path, metavar="PATH", help="write a PNG of the trajectories at the end")
    p.add_argument(
        "--state",
        type=Path,
        metavar="DIR",
        help="keep the simulator's snapshot (time, robots' poses and batteries) in DIR/sim.json and "
        "start from the one there: a `fleet sim` killed and started again with the same --state puts "
        "its robots back where they were (default: start from the config, keep nothing)",
    )
    return p


def handle(args: argparse.Namespace) -> int:
    """Serve until the duration, Ctrl-C or SIGTERM; progress on stdout; the plot at the end."""
    from fleet.bus.session import bus_note
    from fleet.runtime.serve import ServeProgress, serve_simulator
    from fleet.viz.display import FleetSnapshot, ProgressDisplay

    config = load(args)
    endpoint = args.endpoint or config.endpoint
    secure = secure_of(args, config, "router")
    print(
        f"fleet sim: {len(config.robots)} robots of {config.name} on {endpoint} ({bus_note(secure)})",
        flush=True,
    )
    display = ProgressDisplay(sys.stdout, line_every_s=PROGRESS_EVERY_S)

    def show(p: ServeProgress) -> None:
        display.show(
            FleetSnapshot(
                sim_time_s=p.sim_time_s,
                wall_s=p.wall_s,
                duration_s=args.duration,
                robots=len(config.robots),
                note=f"{p.steps} steps, {p.requests} requests, {p.malformed} malformed dropped",
                label="fleet sim",
            )
        )

    try:
        result = serve_simulator(
            config,
            endpoint=endpoint,
            secure=secure,
            speed=args.speed,
            duration=args.duration,
            progress=show,
            progress_every_s=display.interval_s,
            state_dir=args.state,
        )
    finally:
        display.close()
    print(f"fleet sim: {result.malformed} malformed messages dropped", flush=True)
    if args.plot is not None:
        from fleet.viz.plot import plot_run

        sim = result.simulator
        trajectories = {r.name: sim.trajectory(r.namespace) for r in config.robots}
        plot_run(config, trajectories, args.plot, title=f"{config.name}: {len(config.robots)} robots")
        print(f"plot: {args.plot}")
    return EXIT_INTERRUPTED if result.interrupted else EXIT_OK
