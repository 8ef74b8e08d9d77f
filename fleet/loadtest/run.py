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
:data:`DEFAULT_STATUS_HZ`: the config's ``bus.status_hz``, which the agents honour; the
in-process coordinator still sees every tick's status). Both are written to the report.

Nothing here prints: :func:`run_loadtest` reports its progress to callbacks (``fleet loadtest``
shows it with :mod:`fleet.viz.display`).

Units: simulated seconds unless a name says ``wall``; meters in the ``map`` frame."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.config.model import FleetConfig
from fleet.errors import ConfigError
from fleet.loadtest.sampler import DEFAULT_SAMPLE_S, HEAT_BIN_M, FleetSampler, loadtest_block
from fleet.viz.display import FleetSnapshot, NullDisplay

if TYPE_CHECKING:
    from fleet.loadtest.lockstep import RunSpec
    from fleet.runtime.report import RunReport

#: Default agent tick rate of a load test (simulated Hz).
DEFAULT_TICK_HZ = 2.0


#: Default rate at which each agent publishes its status on the bus (simulated Hz).
DEFAULT_STATUS_HZ = 1.0


#: Default of ``--status-max-period``: a robot's status goes on the bus when it changed, and at
#: least this often (simulated s; below the coordinator's 3 s silence timeout).
DEFAULT_STATUS_MAX_PERIOD_S = 2.0


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
    status_max_period_s: float | None = DEFAULT_STATUS_MAX_PERIOD_S,
) -> FleetConfig:
    """Generate the warehouse for ``n_robots`` into ``out_dir`` and load it as a load-test config.

    The config's ``agent.tick_hz``, ``bus.status_hz`` and (if given) ``sim.step_s`` are replaced;
    ``route_copies > 1`` adds ``route_copies - 1`` copies of every patrol route (``<route>_c2``,
    ...), so that up to ``route_copies`` robots patrol each loop (``None``:
    :func:`auto_route_copies`). Raises :class:`ConfigError`
    for values that cannot work (e.g. a tick period shorter than the step).
    """
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
    cfg.status_max_period_s = status_max_period_s
    if route_copies > 1:
        base = list(cfg.routes)
        for c in range(2, route_copies + 1):
            cfg.routes.extend(dataclasses.replace(r, name=f"{r.name}_c{c}", robot=None) for r in base)
    return cfg


def auto_route_copies(cfg: FleetConfig) -> int:
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

    report: RunReport
    data: dict[str, Any]
    report_path: Path
    plots: dict[str, Path]
    interrupted: bool


@dataclass(frozen=True)
class _Outputs:
    """Where a load test writes: the generated warehouse, the report and the plots."""

    out_dir: Path
    report_path: Path
    plot_dir: Path


def _check(
    n_robots: int,
    backend: str,
    rates: dict[str, float],
    out_dir: str | Path | None,
    report_path: str | Path | None,
    plot_dir: str | Path | None,
) -> _Outputs:
    """Validate the arguments (:class:`ConfigError` naming the option) and resolve the paths."""
    from fleet.runtime.backends import BACKENDS, backend_names

    src = "fleet loadtest"
    for name, val in rates.items():
        if not (math.isfinite(val) and val > 0):
            raise ConfigError(src, name, f"must be a positive number, got {val}")
    if backend not in BACKENDS:
        raise ConfigError(
            src, "--backend", f"unknown backend {backend!r}; known: {', '.join(backend_names())}"
        )
    out = Path(out_dir) if out_dir is not None else Path("out") / f"loadtest-{n_robots}"
    return _Outputs(
        out,
        Path(report_path) if report_path is not None else out / "report.json",
        Path(plot_dir) if plot_dir is not None else out,
    )


# long: argument checks, the config, the run (in one process or over workers) and the outputs
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
    traffic: bool = True,
    on_config: Callable[[FleetConfig], None] | None = None,
    on_progress: Callable[[FleetSnapshot], None] | None = None,
    workers: int = 0,
    local_workers: int | None = None,
    status_max_period_s: float | None = DEFAULT_STATUS_MAX_PERIOD_S,
    on_line: Callable[[str], None] | None = None,
) -> LoadTestResult:
    """Run one load test (see the module docstring) and write its report and plots.

    Defaults: ``out_dir`` ``out/loadtest-<N>``; ``report_path`` ``<out_dir>/report.json``;
    ``plot_dir`` ``out_dir``; ``endpoint`` a free TCP port on 127.0.0.1. ``on_config`` is
    called with the generated config before the run; ``on_progress`` with a progress snapshot
    every few wall seconds. ``workers`` > 0 runs the agents in that many worker processes in
    lockstep with this one (:mod:`fleet.loadtest.distributed`; ``local_workers`` of them started
    here, default all; ``on_line`` gets their progress lines); 0 runs them in this process.
    Raises :class:`ConfigError` for bad arguments, :class:`BusError` / :class:`BackendError`
    when the bus or backend cannot be set up.
    """
    if workers < 0 or (local_workers is not None and not 0 <= local_workers <= workers):
        raise ConfigError(
            "fleet loadtest",
            "--workers",
            f"need workers >= 0 and 0 <= local workers <= workers, got {workers}, {local_workers}",
        )
    if workers and backend != "sim":
        raise ConfigError("fleet loadtest", "--workers", "agents in worker processes need the sim backend")
    rates = {"--tick-hz": tick_hz, "--status-hz": status_hz, "--sample-s": sample_s}
    paths = _check(n_robots, backend, rates, out_dir, report_path, plot_dir)
    cfg = prepare_config(
        n_robots,
        paths.out_dir,
        tick_hz=tick_hz,
        status_hz=status_hz,
        step_s=step_s,
        route_copies=route_copies,
        seed=seed,
        status_max_period_s=status_max_period_s,
    )
    if workers > len(cfg.robots):
        raise ConfigError(
            "fleet loadtest", "--workers", f"more workers ({workers}) than robots ({len(cfg.robots)})"
        )
    if on_config is not None:
        on_config(cfg)
    sampler = FleetSampler(len(cfg.robots), cfg.grid.extent, sample_s=sample_s, on_progress=on_progress)
    spec = None
    if workers:
        from fleet.loadtest.distributed import assign
        from fleet.loadtest.lockstep import RunSpec

        spec = RunSpec(
            n_robots, seed, tick_hz, status_hz, status_max_period_s, step_s, route_copies, traffic,
            assign([r.name for r in cfg.robots], workers),
        )  # fmt: skip
    report = _run(
        cfg,
        sampler,
        duration,
        backend=backend,
        speed=speed,
        endpoint=endpoint,
        traffic=traffic,
        spec=spec,
        local_workers=local_workers,
        log_dir=paths.out_dir / "workers",
        on_line=on_line,
    )
    data = report.to_dict()
    data["loadtest"] = loadtest_block(
        report, sampler, backend=backend, tick_hz=tick_hz, status_hz=status_hz, step_s=cfg.sim.step_s
    )
    base = [r for r in cfg.routes if not re.search(r"_c\d+$", r.name)]
    data["loadtest"]["workers"] = workers
    data["loadtest"]["status_max_period_s"] = status_max_period_s
    data["loadtest"]["patrol_routes"] = len(cfg.routes)
    data["loadtest"]["route_copies"] = len(cfg.routes) // max(1, len(base))
    plots = _plot(cfg, sampler, data, report, paths.plot_dir, backend=backend, dpi=dpi)
    data["loadtest"]["plots"] = {k: str(v) for k, v in plots.items()}
    paths.report_path.parent.mkdir(parents=True, exist_ok=True)
    paths.report_path.write_text(json.dumps(data, indent=2) + "\n")
    return LoadTestResult(report, data, paths.report_path, plots, bool(report.interrupted))


def _run(
    cfg: FleetConfig,
    sampler: FleetSampler,
    duration: float,
    *,
    backend: str,
    speed: float,
    endpoint: str | None,
    traffic: bool,
    spec: RunSpec | None = None,
    local_workers: int | None = None,
    log_dir: Path | None = None,
    on_line: Callable[[str], None] | None = None,
) -> RunReport:
    """The fleet run of a load test, sampled by ``sampler`` (its final state included); with
    ``spec`` the agents run in its workers."""
    from fleet.runtime.runner import FleetRunner

    kw: dict[str, Any] = {
        "duration": duration,
        "speed": speed,
        "endpoint": endpoint or _free_endpoint(),
        "backend": backend,
        "live": False,
        "display": NullDisplay(),  # the sampler reports the progress
        "traffic": traffic,
    }
    runner: FleetRunner
    if spec is None:
        runner = FleetRunner(cfg, **kw)
    else:
        from fleet.loadtest.distributed import DistributedRunner

        runner = DistributedRunner(
            cfg, spec, local_workers=local_workers, log_dir=log_dir, progress=on_line, **kw
        )
    runner.observers.append(sampler)
    sampler.start()
    report = runner.run()
    if runner.world is not None and report.sim_time_s > (sampler.t[-1] if sampler.t else -1) + 1e-6:
        sampler.sample(report.sim_time_s, runner, time.monotonic())  # the final state
    return report


def _plot(
    cfg: FleetConfig,
    sampler: FleetSampler,
    data: dict[str, Any],
    report: RunReport,
    plot_dir: Path,
    *,
    backend: str,
    dpi: int,
) -> dict[str, Path]:
    """The three pictures of the load test (see :mod:`fleet.viz.loadtest_plots`)."""
    from fleet.viz.loadtest_plots import plot_congestion, plot_states, plot_throughput

    title = f"{report.robots} robots, {backend}, {report.sim_time_s:.0f} s simulated"
    series = data["loadtest"]["series"]
    return {
        "throughput": plot_throughput(series, plot_dir / "throughput.png", title=title, dpi=dpi),
        "states": plot_states(series, plot_dir / "states.png", title=title, dpi=dpi),
        "congestion": plot_congestion(
            cfg, sampler.heat, plot_dir / "congestion.png", bin_m=HEAT_BIN_M, title=title, dpi=dpi
        ),
    }
