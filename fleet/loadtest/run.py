"""Load tests: ``fleet loadtest --robots N --duration S [--backend sim|sumo]``.

A load test generates a warehouse sized for ``N`` robots (:func:`fleet.warehouse.generate_warehouse`,
into ``--out``, default ``out/loadtest-N``), runs the whole fleet in one process with
:class:`fleet.runtime.runner.FleetRunner` (in-process simulator or SUMO, no live table) and samples the
fleet every ``--sample-s`` simulated seconds through the runner's ``observers`` hook:

* laps completed so far (the coordinator's count), collisions, deadlocks;
* robots per state: the tree's mode (``patrol``, ``picking``, ``charging``, ``recovery``,
  ``idle``), overridden by ``stuck`` (the backend reports the robot stuck) and ``dead`` (the
  coordinator considers it dead);
* *waiting* robots: in a driving mode (``patrol`` / ``recovery``) but moved less than
  :data:`WAIT_SPEED_MPS` on average since the previous sample, or stuck. Their positions
  build the congestion heat map (a 2-D histogram over the map, :data:`HEAT_BIN_M` cells).

At the end it writes the report JSON of ``fleet run`` (:class:`fleet.runtime.report.RunReport`) plus a
``loadtest`` block (:func:`loadtest_block`), and three PNGs (:mod:`fleet.viz.loadtest_plots`):
``throughput.png``, ``states.png`` and ``congestion.png``.

Large fleets: agents tick at ``--tick-hz`` (default :data:`DEFAULT_TICK_HZ`) instead of the
config's 10 Hz and publish their status on the bus at ``--status-hz`` (default
:data:`DEFAULT_STATUS_HZ`; the in-process coordinator still sees every tick's status). Both
are written to the report.

Units: simulated seconds unless a name says ``wall``; meters in the ``map`` frame."""

from __future__ import annotations

import json
import math
import re
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from fleet.errors import ConfigError
from fleet.loadtest.sampler import DEFAULT_SAMPLE_S, HEAT_BIN_M, FleetSampler, loadtest_block

#: Default agent tick rate of a load test (simulated Hz).
DEFAULT_TICK_HZ = 2.0


#: Default rate at which each agent publishes its status on the bus (simulated Hz).
DEFAULT_STATUS_HZ = 1.0


#: Automatic route copies keep at least this much loop length per patrolling robot (m).
PATROL_SPACING_M = 10.0


def _free_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def prepare_config(
    n_robots: int,
    out_dir: str | Path,
    *,
    tick_hz: float = DEFAULT_TICK_HZ,
    status_hz: float = DEFAULT_STATUS_HZ,
    step_s: float | None = None,
    route_copies: int | None = None,
    seed: int = 1,
) -> Any:
    """Generate the warehouse for ``n_robots`` into ``out_dir`` and load it as a load-test config.

    The config's ``agent.tick_hz``, ``bus.status_hz`` and (if given) ``sim.step_s`` are replaced;
    ``route_copies > 1`` adds ``route_copies - 1`` copies of every patrol route (``<route>_c2``,
    ...), so that up to ``route_copies`` robots patrol each loop (``None``:
    :func:`auto_route_copies`). Raises :class:`ConfigError`
    for values that cannot work (e.g. a tick period shorter than the step).
    """
    import dataclasses

    from fleet.config.loader import load_config
    from fleet.warehouse import generate_warehouse

    src = "fleet loadtest"
    if n_robots < 1:
        raise ConfigError(src, "--robots", f"must be at least 1, got {n_robots}")
    path = generate_warehouse(out_dir, f"loadtest_{n_robots}", n_robots, seed=seed)
    cfg = load_config(path)
    if route_copies is None:
        route_copies = auto_route_copies(cfg)
    if route_copies < 1:
        raise ConfigError(src, "--route-copies", f"must be at least 1, got {route_copies}")
    if step_s is not None:
        cfg.sim = dataclasses.replace(cfg.sim, step_s=float(step_s))
    if 1.0 / tick_hz < cfg.sim.step_s - 1e-12:
        raise ConfigError(
            src, "--tick-hz", f"tick period 1/{tick_hz:g} s is shorter than the step ({cfg.sim.step_s:g} s)"
        )
    cfg.tick_hz = float(tick_hz)
    cfg.status_hz = float(status_hz)
    if route_copies > 1:
        base = list(cfg.routes)
        for c in range(2, route_copies + 1):
            cfg.routes.extend(dataclasses.replace(r, name=f"{r.name}_c{c}", robot=None) for r in base)
    return cfg


def auto_route_copies(cfg: Any) -> int:
    """Robots per patrol loop when ``--route-copies`` is not given: enough for half the fleet,
    but at most one robot per :data:`PATROL_SPACING_M` of the shortest loop, and at least 1."""
    n, routes = len(cfg.robots), len(cfg.routes)
    if routes == 0:
        return 1
    laps = []
    for r in cfg.routes:
        poses = cfg.route_poses(r)
        laps.append(sum(poses[i].distance_to(poses[(i + 1) % len(poses)]) for i in range(len(poses))))
    by_space = int(min(laps) // PATROL_SPACING_M)
    return max(1, min(math.ceil(n / (2 * routes)), by_space))


@dataclass
class LoadTestResult:
    """What :func:`run_loadtest` produced: the run report, the full JSON dict and file paths."""

    report: Any
    data: dict[str, Any]
    report_path: Path
    plots: dict[str, Path]
    interrupted: bool


def run_loadtest(
    n_robots: int,
    duration: float,
    *,
    backend: str = "sim",
    out_dir: str | Path | None = None,
    report_path: str | Path | None = None,
    plot_dir: str | Path | None = None,
    tick_hz: float = DEFAULT_TICK_HZ,
    status_hz: float = DEFAULT_STATUS_HZ,
    step_s: float | None = None,
    sample_s: float = DEFAULT_SAMPLE_S,
    speed: float = 0.0,
    route_copies: int | None = None,
    seed: int = 1,
    endpoint: str | None = None,
    dpi: int = 100,
    out: TextIO | None = None,
    traffic: bool = False,
) -> LoadTestResult:
    """Run one load test (see the module docstring) and write its report and plots.

    Defaults: ``out_dir`` ``out/loadtest-<N>``; ``report_path`` ``<out_dir>/report.json``;
    ``plot_dir`` ``out_dir``; ``endpoint`` a free TCP port on 127.0.0.1. Raises
    :class:`ConfigError` for bad arguments, :class:`BusError` / :class:`BackendError` when the
    bus or backend cannot be set up.
    """
    from fleet.runtime.backends import BACKENDS, backend_names
    from fleet.runtime.runner import FleetRunner

    stream = out or sys.stdout
    src = "fleet loadtest"
    for name, val in (("--tick-hz", tick_hz), ("--status-hz", status_hz), ("--sample-s", sample_s)):
        if not (math.isfinite(val) and val > 0):
            raise ConfigError(src, name, f"must be a positive number, got {val}")
    if backend not in BACKENDS:
        raise ConfigError(
            src, "--backend", f"unknown backend {backend!r}; known: {', '.join(backend_names())}"
        )
    out_dir = Path(out_dir) if out_dir is not None else Path("out") / f"loadtest-{n_robots}"
    report_path = Path(report_path) if report_path is not None else out_dir / "report.json"
    plot_dir = Path(plot_dir) if plot_dir is not None else out_dir
    w0 = time.monotonic()
    cfg = prepare_config(
        n_robots,
        out_dir,
        tick_hz=tick_hz,
        status_hz=status_hz,
        step_s=step_s,
        route_copies=route_copies,
        seed=seed,
    )
    print(
        f"fleet loadtest: {len(cfg.robots)} robots, {len(cfg.routes)} patrol routes, map "
        f"{cfg.grid.extent[1]:g} x {cfg.grid.extent[3]:g} m, backend {backend}, agents at {tick_hz:g} Hz, "
        f"status at {status_hz:g} Hz, step {cfg.sim.step_s:g} s; config {cfg.path} "
        f"({time.monotonic() - w0:.1f} s)",
        file=stream,
        flush=True,
    )
    sampler = FleetSampler(
        len(cfg.robots), cfg.grid.extent, sample_s=sample_s, status_hz=status_hz, out=stream
    )
    runner = FleetRunner(
        cfg,
        duration=duration,
        speed=speed,
        endpoint=endpoint or _free_endpoint(),
        backend=backend,
        live=False,
        out=_DropRunnerProgress(stream),  # type: ignore[arg-type]  # a write-only TextIO
        traffic=traffic,
    )
    runner.observers.append(sampler)
    sampler.start()
    report = runner.run()
    if runner.world is not None and report.sim_time_s > (sampler.t[-1] if sampler.t else -1) + 1e-6:
        sampler.sample(report.sim_time_s, runner, time.monotonic())  # the final state
    data = report.to_dict()
    data["loadtest"] = loadtest_block(
        report, sampler, backend=backend, tick_hz=tick_hz, status_hz=status_hz, step_s=cfg.sim.step_s
    )
    base = [r for r in cfg.routes if not re.search(r"_c\d+$", r.name)]
    data["loadtest"]["patrol_routes"] = len(cfg.routes)
    data["loadtest"]["route_copies"] = len(cfg.routes) // max(1, len(base))
    from fleet.viz.loadtest_plots import plot_congestion, plot_states, plot_throughput

    title = f"{report.robots} robots, {backend}, {report.sim_time_s:.0f} s simulated"
    series = data["loadtest"]["series"]
    plots = {
        "throughput": plot_throughput(series, plot_dir / "throughput.png", title=title, dpi=dpi),
        "states": plot_states(series, plot_dir / "states.png", title=title, dpi=dpi),
        "congestion": plot_congestion(
            cfg, sampler.heat, plot_dir / "congestion.png", bin_m=HEAT_BIN_M, title=title, dpi=dpi
        ),
    }
    data["loadtest"]["plots"] = {k: str(v) for k, v in plots.items()}
    report_path.parent.mkdir(parents=True, exist_ok=True)
    report_path.write_text(json.dumps(data, indent=2) + "\n")
    return LoadTestResult(report, data, report_path, plots, bool(report.interrupted))


class _DropRunnerProgress:
    """The runner's output stream minus its own progress lines (the sampler prints richer ones)."""

    def __init__(self, stream: TextIO) -> None:
        self._s = stream
        self._dropping = False

    def write(self, text: str) -> int:
        if text.startswith("[t=") or (self._dropping and text == "\n"):
            self._dropping = text != "\n"
            return len(text)
        self._dropping = False
        return self._s.write(text)

    def flush(self) -> None:
        self._s.flush()

    def isatty(self) -> bool:
        return False

    def __getattr__(self, name: str) -> Any:
        return getattr(self._s, name)
