"""``fleet validate``: load a config and report every robot, route and task it defines."""

from __future__ import annotations

import argparse

from fleet.cli.common import EXIT_OK, _load


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
