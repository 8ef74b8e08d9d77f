"""``fleet run``: the whole fleet (or a part of it) in this process."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from fleet.cli.argtypes import non_negative_float, positive_float
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
    load,
    robot_list,
    secure_of,
    state_dir,
)
from fleet.types import TreeKind

if TYPE_CHECKING:
    from fleet.bus.session import Secure
    from fleet.config.model import FleetConfig

EPILOG = """\
examples:
  fleet run configs/warehouse_patrol.yaml                    # real time until Ctrl-C
  fleet run configs/warehouse_patrol.yaml --duration 300 --speed 10
  fleet run configs/warehouse_patrol_30.yaml --speed 0 --duration 600 --report r.json --plot r.png
  fleet run configs/warehouse_patrol.yaml --agents robot1,robot2 --backend remote
      (robots of a `fleet sim` in another process; the other robots run `fleet agent`)
  fleet run configs/warehouse_picking.yaml --tree picking --speed 0 --duration 300
      (the coordinator hands out the config's picks instead of its routes)
  fleet run configs/warehouse_patrol.yaml --api 127.0.0.1:8080 --state out/state/demo
      (tasks at runtime: `fleet task submit go_to --target a3_n`, docs/service.md; run it again
       with the same --state after a crash to resume)
  fleet run configs/warehouse_patrol.yaml --tree nodes/trees/patrol.xml --no-traffic --speed 0 --duration 300
      (every robot runs the BehaviorTree.CPP XML tree; a tree that uses {pick} gets picks)

--duration and --speed are in simulated seconds; --speed 0 runs as fast as the CPU allows.
"""


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet run`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "run",
        handle,
        help="run a fleet: simulator + agents + coordinator in one process",
        description="Start a Zenoh router on the endpoint, the simulator with N robots, one agent (behavior "
        "tree) per robot and the coordinator; show a live table; print a summary at the end.",
        epilog=EPILOG,
    )
    add_config(p)
    p.add_argument(
        "--duration",
        "-d",
        type=positive_float,
        metavar="S",
        help="simulated seconds to run (default: until Ctrl-C)",
    )
    p.add_argument(
        "--speed",
        "-s",
        type=non_negative_float,
        default=1.0,
        metavar="X",
        help="multiple of real time; 0 = as fast as possible (default 1)",
    )
    add_endpoint(p)
    add_secure(
        p,
        "the router's config when this process hosts the router; with --backend remote: coordinator, or the one agent's robot",
    )
    add_outputs(p)
    add_traffic(p)
    add_service(p)
    p.add_argument(
        "--backend", default="sim", metavar="NAME", help="navigation backend (default sim; see docs/cli.md)"
    )
    p.add_argument(
        "--agents",
        default="all",
        metavar="LIST",
        help="robots whose agents run here: all (default) or robot1,robot2",
    )
    p.add_argument("--no-coordinator", action="store_true", help="do not run the coordinator in this process")
    p.add_argument(
        "--tree",
        type=tree_choice,
        default=TreeKind.PATROL,
        metavar="{patrol,picking,tasks,FILE.xml}",
        help="the config's initial tasks: patrol (its routes; default), picking (its picks, each done "
        "once) or tasks (both); every robot runs the tree that takes any task kind at runtime. Or a "
        "BehaviorTree.CPP v4 XML file every robot runs instead (docs/behavior_trees.md; its orders "
        "follow from the keys it reads; traffic management off)",
    )
    return p


def _secure(args: argparse.Namespace, config: FleetConfig, agents: str | list[str]) -> Secure | None:
    """The secured bus of ``fleet run``: the router's keys when it hosts the router (its own
    session is not bound by the access control), else the identity of what it runs."""
    from fleet.runtime.backends import world_factory

    if args.secure is None and config.secure is None:
        return None
    if not getattr(world_factory(args.backend), "bus_elsewhere", False):
        return secure_of(args, config, "router")
    names = [r.name for r in config.robots] if agents == "all" else list(agents)
    if args.no_coordinator:
        identity = names[0] if len(names) == 1 else None
        hosts = f"the agents of {', '.join(names)}"
    else:
        identity = "coordinator" if not names else None
        hosts = f"the coordinator and the agents of {', '.join(names)}"
    return secure_of(args, config, identity, hosts)


def tree_choice(text: str) -> str:
    """``--tree``: a :class:`TreeKind` name or a path ending in ``.xml``."""
    if text in tuple(TreeKind) or text.lower().endswith(".xml"):
        return text
    raise argparse.ArgumentTypeError(f"expected {', '.join(TreeKind)} or a FILE.xml, got {text!r}")


def handle(args: argparse.Namespace) -> int:
    """Run the fleet; print the summary; write the report and plot. Exit code 0, or 130 if
    interrupted."""
    from fleet.runtime.runner import FleetRunner

    config = load(args)
    is_xml = str(args.tree).lower().endswith(".xml")
    agents: str | list[str] = "all" if args.agents == "all" else robot_list(args.agents)
    runner = FleetRunner(
        config,
        secure=_secure(args, config, agents),
        duration=args.duration,
        speed=args.speed,
        endpoint=args.endpoint,
        backend=args.backend,
        agents=agents,
        coordinator=not args.no_coordinator,
        live=False if args.no_live else None,
        tree_kind=TreeKind.PATROL if is_xml else args.tree,
        tree_file=args.tree if is_xml else None,
        traffic=args.traffic,
        state_dir=state_dir(args, config),
        api=args.api,
    )
    announce(runner, f"{len(runner.agent_names)} agents" + ("" if args.no_coordinator else " + coordinator"))
    return finish(runner, runner.run(), args)
