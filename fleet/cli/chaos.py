"""``fleet chaos``: kill a fleet's processes at random and report what survived."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from fleet.cli.argtypes import non_negative_float, positive_float
from fleet.cli.common import (
    EXIT_ERROR,
    EXIT_OK,
    SubParsers,
    add_command,
    add_config,
    add_traffic,
    load,
    secure_of,
)

EXIT_FOUND = 1

EPILOG = """\
examples:
  fleet chaos configs/warehouse_patrol.yaml --duration 1800 --every 8 --seed 1
      the split fleet (fleet sim, fleet coordinator, one fleet agent per robot), 30 simulated minutes
  fleet chaos configs/warehouse_patrol.yaml --mode run --duration 600 --every 15
      one `fleet run` process killed and restarted from its durable task book
  fleet chaos configs/warehouse_patrol.yaml --duration 600 --secure out/keys   # on a secured bus

exit codes: 0 nothing lost, done twice, collided, crashed with a traceback or ran flat (a battery
below 5 %); 1 something was;
2 bad usage / config / keys, or the fleet did not start; 130 interrupted
"""


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet chaos`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "chaos",
        handle,
        help="kill the fleet's processes at random (kill -9), restart them, report what survived",
        description="Run the fleet of CONFIG on a free 127.0.0.1 port and every --every wall seconds kill "
        "one of its processes (chosen with --seed) with kill -9 and start it again, until the fleet has run "
        "--duration simulated seconds. Reports tasks lost, tasks done twice, collisions, tracebacks and per "
        "kill the wall seconds until the process was back and the fleet moving again (docs/faults.md).",
        epilog=EPILOG,
    )
    add_config(p)
    p.add_argument("--duration", "-d", type=positive_float, default=1800.0, metavar="S",
                   help="simulated seconds the fleet runs, summed over restarts (default 1800)")  # fmt: skip
    p.add_argument(
        "--every", type=positive_float, default=8.0, metavar="W", help="wall s between kills (default 8)"
    )
    p.add_argument("--seed", type=int, default=1, help="which processes are killed (default 1)")
    p.add_argument("--speed", "-s", type=positive_float, default=10.0, metavar="X",
                   help="the simulator's multiple of real time (default 10)")  # fmt: skip
    p.add_argument("--mode", choices=("split", "run"), default="split",
                   help="split (default): fleet sim, fleet coordinator and one fleet agent per robot; "
                   "run: one fleet run process")  # fmt: skip
    p.add_argument("--restart-after", type=non_negative_float, default=0.5, metavar="S",
                   help="wall s between a kill and the restart (default 0.5)")  # fmt: skip
    p.add_argument("--settle", type=positive_float, default=120.0, metavar="S",
                   help="hang guard (wall s) of the start, of each recovery and of the end (default 120)")  # fmt: skip
    p.add_argument("--endpoint", metavar="EP", help="Zenoh endpoint (default: a free 127.0.0.1 port)")
    p.add_argument(
        "--out", type=Path, metavar="DIR", help="state directories and logs (default: a new temp dir)"
    )
    p.add_argument("--secure", type=Path, metavar="DIR",
                   help="run every process on a secured bus with the keys of DIR (`fleet keys init CONFIG DIR "
                   "--robots N`; default: the config's bus.secure); the run watches as the observer")  # fmt: skip
    p.add_argument("--kill", type=_kinds, default=(), metavar="KINDS",
                   help="which processes may be killed, comma-separated of sim, coordinator, agent "
                   "(split) or run (default: all)")  # fmt: skip
    add_traffic(p)
    return p


def _kinds(text: str) -> tuple[str, ...]:
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in ("sim", "coordinator", "agent", "run")]
    if not kinds or bad:
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated list of sim, coordinator, agent, run; got {text!r}"
        )
    return kinds


def handle(args: argparse.Namespace) -> int:
    """Run the chaos; print progress, the table of kills and the verdict."""
    from fleet.bus.session import bus_note, checked_secure, free_endpoint
    from fleet.chaos.run import ChaosSpec, report_lines, robot_names, run_chaos

    config = load(args)
    robots = len(config.robots)
    kinds = ("run",) if args.mode == "run" else ("sim", "coordinator", "agent")
    if args.kill and not set(args.kill) & set(kinds):
        print(
            f"fleet chaos: error: --kill {','.join(args.kill)}: --mode {args.mode} has only the "
            f"{' / '.join(kinds)} process to kill",
            file=sys.stderr,
        )
        return EXIT_ERROR
    secure = secure_of(args, config, "observer")
    if secure is not None:
        for identity in robot_names(robots) if args.mode == "split" else []:
            checked_secure(secure.keys, identity)
        checked_secure(secure.keys, "observer")
    out = args.out or Path(tempfile.mkdtemp(prefix="fleet-chaos-"))
    spec = ChaosSpec(
        config=config.path, robots=robots, duration=args.duration, endpoint=args.endpoint or free_endpoint(),
        out=out, speed=args.speed, every=args.every, seed=args.seed, restart_after=args.restart_after,
        settle=args.settle, traffic=config.traffic.enabled if args.traffic is None else args.traffic,
        secure=None if secure is None else secure.keys, mode=args.mode, routes=tuple(r.name for r in config.routes), kinds=args.kill,
    )  # fmt: skip
    print(
        f"fleet chaos: {config.name}, {robots} robots, mode {spec.mode}, {spec.duration:.0f} simulated s at speed "
        f"{spec.speed:g}, a kill every {spec.every:g} wall s, seed {spec.seed}, bus {spec.endpoint} "
        f"({bus_note(secure)}), logs in {out}",
        flush=True,
    )
    res = run_chaos(spec, say=lambda line: print(line, flush=True))
    print()
    for line in report_lines(res):
        print(line)
    return EXIT_OK if res.ok else EXIT_FOUND
