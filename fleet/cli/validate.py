"""``fleet validate``: load a config and report every robot, route and task it defines."""

from __future__ import annotations

import argparse

from fleet.cli.common import EXIT_OK, SubParsers, add_command, add_config, load


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet validate`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "validate",
        handle,
        help="load a config, report the first problem or print a summary",
        description="Load and validate a fleet config. Prints a summary, or one line naming the file, the "
        "field and the reason, and exits 2.",
        epilog="example:\n  fleet validate configs/warehouse_patrol.yaml --robots 30\n",
    )
    add_config(p)
    return p


def handle(args: argparse.Namespace) -> int:
    """Print the config's summary (a bad config raises ConfigError: exit 2)."""
    config = load(args)
    xmin, xmax, ymin, ymax = config.grid.extent
    robots = ", ".join(r.name for r in config.robots[:8]) + (", ..." if len(config.robots) > 8 else "")
    lines = [
        f"{config.path}: ok",
        f"  name:        {config.name}",
        f"  map:         {config.map_path} ({xmax - xmin:g} x {ymax - ymin:g} m, {config.grid.resolution:g} m/cell)",
        f"  roadmap:     {len(config.roadmap)} nodes, {len(config.roadmap.edges)} edges",
        f"  robots:      {len(config.robots)} ({robots})",
        f"  routes:      {len(config.routes)} ({', '.join(r.name for r in config.routes)})",
        f"  tasks:       {len(config.tasks)}",
        f"  chargers:    {len(config.chargers)}   stations: {len(config.stations)}",
        f"  sim:         step {config.sim.step_s:g} s, agents tick at {config.tick_hz:g} Hz",
        f"  bus:         {config.endpoint}"
        + (f", status at {config.status_hz:g} Hz" if config.status_hz else ""),
    ]
    print("\n".join(lines))
    return EXIT_OK
