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
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.config.model import FleetConfig, Route
from fleet.errors import ConfigError
from fleet.loadtest.sampler import DEFAULT_SAMPLE_S, HEAT_BIN_M, FleetSampler, loadtest_block
from fleet.viz.display import FleetSnapshot, NullDisplay

if TYPE_CHECKING:
    from fleet.bus.session import Secure
    from fleet.loadtest.lockstep import RunSpec
    from fleet.runtime.report import RunReport

#: Default agent tick rate of a load test (simulated Hz).
DEFAULT_TICK_HZ = 2.0


#: Default rate at which each agent publishes its status on the bus (simulated Hz).
DEFAULT_STATUS_HZ = 1.0


#: A load test's generated floor holds every robot on a patrol loop with at least this much
#: loop length per robot (m); explicit ``--route-copies`` keep it for the shortest loop.
PATROL_SPACING_M = 8.0

#: Shelf rows of a load test's floor are at most this long (m): a robot in the middle of an
#: aisle stays within half of it of the chargers beside the corridors.
WORK_SHELF_MAX_M = 40.0

#: A load test's floor has a charger per this many robots (:func:`work_chargers`).
ROBOTS_PER_CHARGER = 2

#: Default of ``--status-max-period``: a robot's status goes on the bus when it changed, and at
#: least this often (simulated s; below the coordinator's 3 s silence timeout).
DEFAULT_STATUS_MAX_PERIOD_S = 2.0


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
    ...), so that up to ``route_copies`` robots patrol each loop, on the default floor for
    ``n_robots``. ``None`` (the default): every robot has work: the floor is sized by
    :func:`work_floor` and each loop gets :func:`work_copies` robots, one route per robot. Raises :class:`ConfigError`
    for values that cannot work (e.g. a tick period shorter than the step).
    """
    from fleet.config.loader import load_config
    from fleet.warehouse import generate_warehouse, plan_layout

    src = "fleet loadtest"
    if n_robots < 1:
        raise ConfigError(src, "--robots", f"must be at least 1, got {n_robots}")
    if route_copies is not None and route_copies < 1:
        raise ConfigError(src, "--route-copies", f"must be at least 1, got {route_copies}")
    if route_copies is None:
        aisles, shelf = work_floor(n_robots)
        chargers = min(plan_layout(n_robots, aisles, shelf).charger_capacity, work_chargers(n_robots))
        path = generate_warehouse(
            out_dir,
            f"loadtest_{n_robots}",
            n_robots,
            aisles=aisles,
            shelf_len=shelf,
            chargers=chargers,
            charger_sides=2,  # robots come off every aisle at both ends: charge at both
            seed=seed,
        )
    else:
        path = generate_warehouse(out_dir, f"loadtest_{n_robots}", n_robots, seed=seed)
    cfg = load_config(path)
    if step_s is not None:
        cfg.sim = dataclasses.replace(cfg.sim, step_s=float(step_s))
    if 1.0 / tick_hz < cfg.sim.step_s - 1e-12:
        raise ConfigError(
            src, "--tick-hz", f"tick period 1/{tick_hz:g} s is shorter than the step ({cfg.sim.step_s:g} s)"
        )
    cfg.tick_hz = float(tick_hz)
    cfg.status_hz = float(status_hz)
    cfg.status_max_period_s = status_max_period_s
    base = list(cfg.routes)
    copies = work_copies(cfg, n_robots) if route_copies is None else [route_copies] * len(base)
    for c in range(2, max(copies, default=1) + 1):
        cfg.routes.extend(
            dataclasses.replace(r, name=f"{r.name}_c{c}", robot=None)
            for r, k in zip(base, copies, strict=True)
            if k >= c
        )
    return cfg


def loop_length(cfg: FleetConfig, route: Route) -> float:
    """Length (m) of the closed polygon through ``route``'s waypoints (the roadmap loop of a
    generated route: its waypoints are joined by straight aisles and corridors)."""
    poses = cfg.route_poses(route)
    return sum(poses[i].distance_to(poses[(i + 1) % len(poses)]) for i in range(len(poses)))


def work_chargers(n_robots: int) -> int:
    """Chargers of a load test's floor: one per :data:`ROBOTS_PER_CHARGER` robots. A robot
    that drives all the time drains about 0.0045 of its battery per second at 1 m/s and a
    charger gives 0.02 per second, so a fleet that always works spends about a fifth of its
    time on chargers; the rest covers the trips to and from them."""
    return max(2, math.ceil(n_robots / ROBOTS_PER_CHARGER))


def work_floor(n_robots: int, spacing_m: float = PATROL_SPACING_M) -> tuple[int, float]:
    """``(aisles, shelf_len)`` of a load test's floor on which every one of ``n_robots``
    robots has a patrol loop with ``spacing_m`` of loop each: shelves of
    ``10 + sqrt(n)`` m (at least the default, at most :data:`WORK_SHELF_MAX_M`), and the
    fewest aisles (at least the default) whose loops hold the fleet (:func:`work_copies`)."""
    from fleet.warehouse import auto_aisles, auto_shelf_len, plan_layout, routes_of

    shelf = float(round(min(WORK_SHELF_MAX_M, max(auto_shelf_len(n_robots), 10.0 + math.sqrt(n_robots)))))
    k = auto_aisles(n_robots)
    while True:
        lay = plan_layout(n_robots, k, shelf)
        pair = 2 * (lay.y_north - lay.y_south) + 2 * (lay.aisle_x(2) - lay.aisle_x(1))
        around = 2 * (lay.y_north - lay.y_south) + 2 * (lay.x_east - lay.x_west)
        east = 2 * (lay.y_north - lay.y_south) + 2 * (lay.x_east - lay.aisle_x(k))
        loops = [pair] * (k // 2) + ([east] if k % 2 else []) + [around]
        assert len(loops) == len(routes_of(k))
        if sum(max(1, int(length // spacing_m)) for length in loops) >= n_robots:
            return k, shelf
        k += max(1, k // 20)


def work_copies(cfg: FleetConfig, n_robots: int, spacing_m: float = PATROL_SPACING_M) -> list[int]:
    """Robots per route of ``cfg.routes`` so that ``n_robots`` robots all patrol: each loop
    holds one robot per ``spacing_m`` of its length (at least one); the copies are trimmed
    round-robin (highest copy numbers first) to the fleet size when the loops hold more."""
    cap = [max(1, int(loop_length(cfg, r) // spacing_m)) for r in cfg.routes]
    copies = [0] * len(cap)
    left = n_robots
    for c in range(1, max(cap, default=1) + 1):
        for i, k in enumerate(cap):
            if k >= c and left > 0:
                copies[i] = c
                left -= 1
    return [max(1, c) for c in copies]


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
    ticking: str = "event",
    on_config: Callable[[FleetConfig], None] | None = None,
    on_progress: Callable[[FleetSnapshot], None] | None = None,
    workers: int = 0,
    local_workers: int | None = None,
    status_max_period_s: float | None = DEFAULT_STATUS_MAX_PERIOD_S,
    on_line: Callable[[str], None] | None = None,
    secure: Path | None = None,
    on_setup: Callable[[str], None] | None = None,
) -> LoadTestResult:
    """Run one load test (see the module docstring) and write its report and plots.

    Defaults: ``out_dir`` ``out/loadtest-<N>``; ``report_path`` ``<out_dir>/report.json``;
    ``plot_dir`` ``out_dir``; ``endpoint`` a free TCP port on 127.0.0.1. ``on_config`` is
    called with the generated config before the run; ``on_progress`` with a progress snapshot
    every few wall seconds. ``workers`` > 0 runs the agents in that many worker processes in
    lockstep with this one (:mod:`fleet.loadtest.distributed`; ``local_workers`` of them started
    here, default all; ``on_line`` gets their progress lines); 0 runs them in this process.
    ``secure``: a key directory (``fleet keys init``): the bus is secured with it (this process
    hosts the router; workers connect as its ``worker`` identity, checked before anything runs).
    ``on_setup`` gets a line after each set-up phase (the floor, the config, the world, the
    coordinator, the agents: minutes for thousands of robots) with the resident memory.
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
    keys = None
    if secure is not None:
        from fleet.bus.keyring import ROUTER_USER
        from fleet.bus.session import checked_secure

        keys = checked_secure(secure, "worker" if workers else ROUTER_USER)
    rates = {"--tick-hz": tick_hz, "--status-hz": status_hz, "--sample-s": sample_s}
    paths = _check(n_robots, backend, rates, out_dir, report_path, plot_dir)
    setup = _with_memory(on_setup)
    w0 = time.monotonic()
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
    if setup is not None:
        setup(
            f"setup: floor and config of {len(cfg.robots)} robots ready in {time.monotonic() - w0:.1f} s "
            f"(process CPU {time.process_time():.0f} s)"
        )
    if workers > len(cfg.robots):
        raise ConfigError(
            "fleet loadtest", "--workers", f"more workers ({workers}) than robots ({len(cfg.robots)})"
        )
    if on_config is not None:
        on_config(cfg)
    sampler = FleetSampler(len(cfg.robots), cfg.grid.extent, sample_s=sample_s, on_progress=on_progress)
    ticks: dict[str, int] = {}
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
        ticking=ticking,
        ticks=ticks,
        spec=spec,
        local_workers=local_workers,
        log_dir=paths.out_dir / "workers",
        on_line=on_line,
        secure=keys,
        on_setup=setup,
    )
    data = report.to_dict()
    data["loadtest"] = loadtest_block(
        report, sampler, backend=backend, tick_hz=tick_hz, status_hz=status_hz, step_s=cfg.sim.step_s
    )
    base = [r for r in cfg.routes if not re.search(r"_c\d+$", r.name)]
    data["loadtest"]["ticking"] = ticking
    data["loadtest"]["tree_ticks"] = ticks.get("tree_ticks", 0)
    data["loadtest"]["agent_periods"] = ticks.get("agent_periods", 0)
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
    ticking: str = "event",
    ticks: dict[str, int] | None = None,
    spec: RunSpec | None = None,
    local_workers: int | None = None,
    log_dir: Path | None = None,
    on_line: Callable[[str], None] | None = None,
    secure: Secure | None = None,
    on_setup: Callable[[str], None] | None = None,
) -> RunReport:
    """The fleet run of a load test, sampled by ``sampler`` (its final state included); with
    ``spec`` the agents run in its workers. ``ticks`` gets the trees ticked (``tree_ticks``)
    and the agent periods (``agent_periods``: periods x agents)."""
    from fleet.bus.session import free_endpoint
    from fleet.runtime.runner import FleetRunner

    kw: dict[str, Any] = {
        "duration": duration,
        "speed": speed,
        "endpoint": endpoint or free_endpoint(),
        "backend": backend,
        "live": False,
        "display": NullDisplay(),  # the sampler reports the progress
        "traffic": traffic,
        "ticking": ticking,
        "secure": secure,
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
    runner.on_setup = on_setup
    sampler.start()
    report = runner.run()
    if ticks is not None and runner.scheduler is not None:
        ticks["tree_ticks"] = runner.scheduler.tree_ticks
        ticks["agent_periods"] = runner.scheduler.periods * len(runner.agents)
    if runner.world is not None and report.sim_time_s > (sampler.t[-1] if sampler.t else -1) + 1e-6:
        sampler.sample(report.sim_time_s, runner, time.monotonic())  # the final state
    return report


def _with_memory(out: Callable[[str], None] | None) -> Callable[[str], None] | None:
    """``out`` with this process's resident memory appended to each line."""
    if out is None:
        return None
    from fleet.loadtest.memory import rss_mb

    def line(text: str) -> None:
        out(f"{text}, {rss_mb():.0f} MB resident")

    return line


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
