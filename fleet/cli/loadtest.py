"""``fleet loadtest``: its options and the command."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from fleet.bus.session import Secure, bus_note
from fleet.cli.argtypes import non_negative_float, non_negative_int, positive_float, positive_int
from fleet.cli.common import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_OK,
    SubParsers,
    add_command,
    guard,
    standalone_parser,
)
from fleet.cli.logs import configure_logging, resolve_level
from fleet.config.model import FleetConfig
from fleet.loadtest.run import (
    DEFAULT_STATUS_HZ,
    DEFAULT_STATUS_MAX_PERIOD_S,
    DEFAULT_TICK_HZ,
    PATROL_SPACING_M,
    LoadTestResult,
    run_loadtest,
)
from fleet.loadtest.sampler import DEFAULT_SAMPLE_S
from fleet.viz.display import ProgressDisplay

DESCRIPTION = (
    "Load-test the fleet: generate a warehouse for N robots, run simulator (or SUMO) + one agent "
    "per robot + the coordinator in one process as fast as possible, sample the fleet over "
    "simulated time and write the report JSON (the `fleet run` report plus a `loadtest` block) and "
    "three plots: throughput.png (laps per robot-hour over time), states.png (robots per state "
    "over time), congestion.png (heat map of where robots wait)."
)


EPILOG = """\
examples:
  fleet loadtest --robots 100 --duration 600
  fleet loadtest --robots 1000 --duration 300 --out out/lt1000
  fleet loadtest --robots 5000 --duration 120 --backend sumo --step-s 0.1
  fleet loadtest --robots 20 --duration 60 --tick-hz 10 --status-hz 10 --plot-dir /tmp/plots
  fleet loadtest --robots 1000 --duration 300 --workers 2          # agents in 2 processes
  fleet loadtest --robots 20 --duration 300 --workers 2 --secure out/keys   # on a secured bus
  fleet loadtest --robots 1000 --duration 300 --workers 4 --local-workers 2 --endpoint tcp/0.0.0.0:7447
      # and on another machine: python -m fleet.loadtest.worker --endpoint tcp/HOST:7447 --index 2 (and 3)

defaults for large fleets: agents tick at 2 Hz (--tick-hz) and publish their status at 1 Hz
(--status-hz); the config's agent.tick_hz is 10. Both are written to the report.
exit codes: 0 ok, 2 bad usage / bus or backend error, 130 interrupted (report still written)
"""


# long: one flat list of the command's options reads best
def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``fleet loadtest`` (see ``docs/performance.md``)."""
    p.add_argument("--robots", "-n", type=positive_int, required=True, metavar="N", help="number of robots")
    p.add_argument(
        "--duration", "-d", type=positive_float, required=True, metavar="S", help="simulated seconds to run"
    )
    p.add_argument("--backend", default="sim", metavar="NAME", help="sim (default) or sumo")
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--traffic",
        dest="traffic",
        action="store_true",
        default=True,
        help="reservation-based traffic management (docs/traffic.md); the default",
    )
    g.add_argument("--no-traffic", dest="traffic", action="store_false", help="no traffic management")
    p.add_argument(
        "--speed",
        "-s",
        type=non_negative_float,
        default=0.0,
        metavar="X",
        help="multiple of real time; 0 = as fast as possible (default)",
    )
    p.add_argument(
        "--out", type=Path, metavar="DIR", help="generated warehouse and outputs (default out/loadtest-N)"
    )
    p.add_argument("--report", type=Path, metavar="PATH", help="report JSON (default DIR/report.json)")
    p.add_argument("--plot-dir", type=Path, metavar="DIR", help="where the three PNGs go (default --out)")
    p.add_argument(
        "--tick-hz",
        type=positive_float,
        default=DEFAULT_TICK_HZ,
        metavar="HZ",
        help=f"agent tick rate, simulated Hz (default {DEFAULT_TICK_HZ:g})",
    )
    p.add_argument(
        "--status-hz",
        type=positive_float,
        default=DEFAULT_STATUS_HZ,
        metavar="HZ",
        help=f"status publishing rate per robot on the bus (default {DEFAULT_STATUS_HZ:g})",
    )
    p.add_argument(
        "--step-s", type=positive_float, metavar="S", help="simulator step (default: the config's, 0.05 s)"
    )
    p.add_argument(
        "--sample-s",
        type=positive_float,
        default=DEFAULT_SAMPLE_S,
        metavar="S",
        help=f"sampling period of the time series (default {DEFAULT_SAMPLE_S:g} s)",
    )
    p.add_argument(
        "--route-copies",
        type=positive_int,
        default=None,
        metavar="K",
        help="K robots patrol each route of the default floor for N robots (default: every robot "
        f"patrols: the floor is sized so that its loops hold one robot per {PATROL_SPACING_M:g} m)",
    )
    p.add_argument(
        "--ticking",
        choices=("event", "clock"),
        default="event",
        help="event (default): a robot's tree ticks only when something it reads changed, with the "
        "same decisions as ticking it every period; clock: every tree every period",
    )
    p.add_argument(
        "--status-max-period",
        type=non_negative_float,
        default=DEFAULT_STATUS_MAX_PERIOD_S,
        metavar="S",
        help="statuses go on the bus when they changed, and at least every S simulated s "
        f"(default {DEFAULT_STATUS_MAX_PERIOD_S:g}; 0: at every --status-hz period)",
    )
    p.add_argument(
        "--workers",
        type=non_negative_int,
        default=0,
        metavar="K",
        help="run the agents in K worker processes, in lockstep with this one (simulator, coordinator); "
        "same outcomes as in one process. 0 (default): agents in this process",
    )
    p.add_argument(
        "--local-workers",
        type=non_negative_int,
        default=None,
        metavar="L",
        help="start only workers 0..L-1 here (default: all K); start the others with "
        "`python -m fleet.loadtest.worker --endpoint EP --index I`, on this or other machines",
    )
    p.add_argument("--seed", type=int, default=1, help="warehouse and simulator seed (default 1)")
    p.add_argument("--endpoint", metavar="EP", help="Zenoh endpoint to listen on (default: a free port)")
    p.add_argument("--dpi", type=positive_int, default=100, help="PNG resolution (default 100)")
    p.add_argument(
        "--secure",
        type=Path,
        metavar="DIR",
        help="secured bus: this process hosts the router with the keys of DIR (`fleet keys init`); "
        "workers connect as its `worker` identity; `fleet status --secure DIR` attaches as the observer",
    )


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet loadtest`` to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "loadtest",
        handle,
        help="load-test the fleet with N robots: report JSON and plots",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    add_arguments(p)
    return p


def build_parser() -> argparse.ArgumentParser:
    """The parser of :func:`loadtest_main` (the options of ``fleet loadtest``)."""
    return standalone_parser("fleet loadtest", DESCRIPTION, EPILOG, add_arguments)


def handle(args: argparse.Namespace) -> int:
    """Run the load test parsed into ``args`` (progress on stdout); print the summary; return
    the exit code."""
    w0 = time.monotonic()
    display = ProgressDisplay(sys.stdout)

    bus = bus_note(None if args.secure is None else Secure(args.secure, "router"))

    def announce(cfg: FleetConfig) -> None:
        xmax, ymax = cfg.grid.extent[1], cfg.grid.extent[3]
        print(
            f"fleet loadtest: {len(cfg.robots)} robots, {len(cfg.routes)} patrol routes, map {xmax:g} x {ymax:g} m, "
            f"backend {args.backend}, agents at {args.tick_hz:g} Hz, status at {args.status_hz:g} Hz, "
            f"step {cfg.sim.step_s:g} s; config {cfg.path} ({time.monotonic() - w0:.1f} s); {bus}",
            flush=True,
        )

    try:
        res = run_loadtest(
            args.robots,
            args.duration,
            backend=args.backend,
            out_dir=args.out,
            report_path=args.report,
            plot_dir=args.plot_dir,
            tick_hz=args.tick_hz,
            status_hz=args.status_hz,
            step_s=args.step_s,
            sample_s=args.sample_s,
            speed=args.speed,
            route_copies=args.route_copies,
            seed=args.seed,
            endpoint=args.endpoint,
            dpi=args.dpi,
            traffic=args.traffic,
            ticking=args.ticking,
            on_config=announce,
            on_progress=display.show,
            workers=args.workers,
            local_workers=args.local_workers,
            status_max_period_s=args.status_max_period or None,
            on_line=lambda line: print(f"fleet loadtest: {line}", flush=True),
            secure=args.secure,
            on_setup=lambda line: print(f"fleet loadtest: {line}", flush=True),
        )
    finally:
        display.close()
    _print_summary(res)
    return EXIT_INTERRUPTED if res.interrupted else EXIT_OK


def _print_summary(res: LoadTestResult) -> None:
    lt = res.data["loadtest"]
    r = res.report
    wait = lt["mean_wait_s"]
    print(
        f"{'interrupted' if r.interrupted else 'finished'}: {r.robots} robots, {r.sim_time_s:.1f} s simulated in "
        f"{r.wall_time_s:.1f} s wall (setup {lt['setup_wall_s']:.1f} s, loop {lt['real_time_factor']:.2f}x real time)\n"
        f"patrols: {r.patrols_assigned} assigned, {r.patrols_completed} completed, {r.laps_completed} laps "
        f"({lt['throughput_laps_per_robot_hour']:.2f} per robot-hour, "
        f"{lt['throughput_laps_per_patrolling_robot_hour']:.2f} per patrolling robot-hour)\n"
        f"collisions: {r.collisions}   deadlocks: {r.deadlocks}   reassignments: {r.reassignments}   "
        f"mean wait: {'n/a' if wait is None else f'{wait:.1f} s'} per driving robot\n"
        f"report: {res.report_path}",
        flush=True,
    )
    for p in res.plots.values():
        print(f"plot: {p}")


def loadtest_main(argv: Sequence[str] | None = None) -> int:
    """``fleet loadtest`` as a function: 0 ok, 2 bad usage or setup error, 130 interrupted."""
    try:
        args = build_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    except SystemExit as e:  # argparse: --help (0) or bad usage (2), message already printed
        return int(e.code) if isinstance(e.code, int) else EXIT_ERROR
    return guard(lambda: _configured(args))


def _configured(args: argparse.Namespace) -> int:
    configure_logging(resolve_level(args.log_level))
    return handle(args)
