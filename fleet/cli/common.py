"""What every ``fleet`` command shares: exit codes, common options, the error guard, config loading."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from fleet.cli.argtypes import positive_int as _positive_int
from fleet.errors import BackendError, BusError, ConfigError

EXIT_OK = 0


EXIT_ERROR = 2


EXIT_INTERRUPTED = 130


def _add_config(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, help="fleet config YAML (see docs/config.md)")
    p.add_argument(
        "--robots",
        "-n",
        type=_positive_int,
        metavar="N",
        help="number of robots (default: as listed in the config)",
    )


def _add_endpoint(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--endpoint",
        metavar="EP",
        help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (default: the config's bus.endpoint)",
    )


def _add_traffic(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--traffic",
        dest="traffic",
        action="store_true",
        default=None,
        help="reservation-based traffic management on the roadmap (default: the config's traffic.enabled)",
    )
    g.add_argument("--no-traffic", dest="traffic", action="store_false", help="no traffic management")


def _add_outputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--report", type=Path, metavar="PATH", help="write the JSON report here at the end")
    p.add_argument("--plot", type=Path, metavar="PATH", help="write a PNG of the map and trajectories here")
    p.add_argument(
        "--no-live", action="store_true", help="no live table; print a progress line every 5 s instead"
    )


def _sigterm_as_interrupt() -> Any:
    """Make SIGTERM raise KeyboardInterrupt (so ``finally`` blocks close the Zenoh session);
    returns the previous handler (None off the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, handler)


def _guard(fn: Any) -> int:
    old = _sigterm_as_interrupt()
    try:
        return int(fn())
    except (ConfigError, BusError, BackendError) as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def _load(args: argparse.Namespace) -> Any:
    from fleet.config.loader import load_config

    return load_config(args.config, robots=args.robots)


def _robot_list(text: str) -> list[str]:
    return [r.strip() for r in text.split(",") if r.strip()]


def _finish(runner: Any, report: Any, args: argparse.Namespace) -> int:
    print(report.summary(), flush=True)
    if getattr(args, "report", None):
        path = report.write_json(args.report)
        print(f"report: {path}")
    if getattr(args, "plot", None):
        from fleet.viz.plot import plot_run

        title = (
            f"{runner.config.name}: {report.robots} robots, {report.sim_time_s:.0f} s simulated, "
            f"{report.collisions} collisions, {report.laps_completed} laps"
        )
        path = plot_run(
            runner.config, report.trajectories, args.plot, title=title, collisions=runner.collision_points()
        )
        print(f"plot: {path}")
    return EXIT_INTERRUPTED if report.interrupted else EXIT_OK


def _announce(runner: Any, what: str) -> None:
    print(
        f"fleet: {runner.config.name}, {what}, backend {runner.backend_name}, bus {runner.endpoint}",
        file=runner.out,
        flush=True,
    )
