"""Load tests: ``fleet loadtest --robots N --duration S [--backend sim|sumo]``.

A load test generates a warehouse sized for ``N`` robots (:func:`fleet.warehouse.generate_warehouse`,
into ``--out``, default ``out/loadtest-N``), runs the whole fleet in one process with
:class:`fleet.runner.FleetRunner` (in-process simulator or SUMO, no live table) and samples the
fleet every ``--sample-s`` simulated seconds through the runner's ``observers`` hook:

* laps completed so far (the coordinator's count), collisions, deadlocks;
* robots per state: the tree's mode (``patrol``, ``picking``, ``charging``, ``recovery``,
  ``idle``), overridden by ``stuck`` (the backend reports the robot stuck) and ``dead`` (the
  coordinator considers it dead);
* *waiting* robots: in a driving mode (``patrol`` / ``recovery``) but moved less than
  :data:`WAIT_SPEED_MPS` on average since the previous sample, or stuck. Their positions
  build the congestion heat map (a 2-D histogram over the map, :data:`HEAT_BIN_M` cells).

At the end it writes the report JSON of ``fleet run`` (:class:`fleet.report.RunReport`) plus a
``loadtest`` block (:func:`loadtest_block`), and three PNGs (:mod:`fleet.loadtest_plots`):
``throughput.png``, ``states.png`` and ``congestion.png``.

Large fleets: agents tick at ``--tick-hz`` (default :data:`DEFAULT_TICK_HZ`) instead of the
config's 10 Hz and publish their status on the bus at ``--status-hz`` (default
:data:`DEFAULT_STATUS_HZ`; the in-process coordinator still sees every tick's status). Both
are written to the report.

Units: simulated seconds unless a name says ``wall``; meters in the ``map`` frame.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import socket
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from fleet.argtypes import non_negative_float, positive_float, positive_int
from fleet.errors import BackendError, BusError, ConfigError

#: Default agent tick rate of a load test (simulated Hz).
DEFAULT_TICK_HZ = 2.0
#: Default rate at which each agent publishes its status on the bus (simulated Hz).
DEFAULT_STATUS_HZ = 1.0
#: Default sampling period of the time series (simulated seconds).
DEFAULT_SAMPLE_S = 5.0
#: Throughput is also reported over a sliding window of this many simulated seconds.
THROUGHPUT_WINDOW_S = 60.0
#: A robot in a driving mode slower than this on average between two samples is waiting (m/s).
WAIT_SPEED_MPS = 0.1
#: Cell size of the congestion heat map (m).
HEAT_BIN_M = 1.0
#: Automatic route copies keep at least this much loop length per patrolling robot (m).
PATROL_SPACING_M = 10.0
#: Progress lines are printed this often (wall seconds).
PROGRESS_EVERY_S = 5.0
#: Robot states in the ``states`` time series, in plotting order.
STATES = ("patrol", "picking", "recovery", "charging", "idle", "stuck", "dead")
DRIVING_MODES = ("patrol", "recovery", "picking")
#: Fields of the ``loadtest`` block of the report.
LOADTEST_FIELDS = (
    "backend",
    "tick_hz",
    "status_hz",
    "step_s",
    "sample_s",
    "real_time_factor",
    "setup_wall_s",
    "throughput_laps_per_robot_hour",
    "mean_wait_s",
    "series",
    "congestion",
    "plots",
)
#: Keys of ``loadtest.series`` (each a list with one entry per sample; ``states`` a dict of lists).
SERIES_FIELDS = (
    "t_s",
    "wall_s",
    "laps",
    "throughput_laps_per_robot_hour",
    "throughput_window_laps_per_robot_hour",
    "waiting",
    "collisions",
    "deadlocks",
    "states",
)


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

    from fleet.config import load_config
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


class _ThrottledBus:
    """A status bus proxy that publishes each robot's status at most every ``period_s``
    (simulated seconds, from the record's ``t``); everything else goes to ``bus``."""

    def __init__(self, bus: Any, period_s: float) -> None:
        self._bus = bus
        self._period = period_s
        self._last: dict[str, float] = {}

    def publish_status(self, rec: Any) -> None:
        last = self._last.get(rec.robot)
        if last is None or rec.t >= last + self._period - 1e-9:
            self._last[rec.robot] = rec.t
            self._bus.publish_status(rec)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._bus, name)


@dataclass
class FleetSampler:
    """The runner observer of a load test: samples the fleet every ``sample_s`` simulated
    seconds, prints a progress line every :data:`PROGRESS_EVERY_S` wall seconds and throttles
    the agents' status publishing to ``status_hz``. See the module docstring for the metrics.

    ``extent`` is the map's ``(xmin, xmax, ymin, ymax)`` (m); ``n_robots`` normalizes the
    throughput (laps per robot-hour over every robot of the fleet).
    """

    n_robots: int
    extent: tuple[float, float, float, float]
    sample_s: float = DEFAULT_SAMPLE_S
    status_hz: float | None = None
    out: TextIO | None = None
    t: list[float] = field(default_factory=list)
    wall: list[float] = field(default_factory=list)
    laps: list[int] = field(default_factory=list)
    waiting: list[int] = field(default_factory=list)
    collisions: list[int] = field(default_factory=list)
    deadlocks: list[int] = field(default_factory=list)
    states: dict[str, list[int]] = field(default_factory=lambda: {s: [] for s in STATES})
    wait_robot_s: float = 0.0
    setup_wall_s: float | None = None

    def __post_init__(self) -> None:
        xmin, xmax, ymin, ymax = self.extent
        self.nx = max(1, math.ceil((xmax - xmin) / HEAT_BIN_M))
        self.ny = max(1, math.ceil((ymax - ymin) / HEAT_BIN_M))
        self.heat = np.zeros((self.ny, self.nx), dtype=np.int64)
        self._prev: dict[str, tuple[float, float]] = {}
        self.drivers: set[str] = set()
        self._next_sample: float | None = None
        self._t_last_sample: float | None = None
        self._wall0 = time.monotonic()
        self._loop_wall0: float | None = None
        self._loop_t0 = 0.0
        self._next_progress = 0.0
        self._throttled = False

    def start(self) -> None:
        """Mark the wall-clock start of the run (before the runner sets up)."""
        self._wall0 = time.monotonic()

    def __call__(self, now: float, runner: Any) -> None:
        w = time.monotonic()
        if self._loop_wall0 is None:
            self._loop_wall0 = w
            self._loop_t0 = now
            self.setup_wall_s = w - self._wall0
            self._next_progress = w + PROGRESS_EVERY_S
            self._throttle(runner)
        if self._next_sample is None or now >= self._next_sample - 1e-9:
            self.sample(now, runner, w)
            self._next_sample = (now if self._next_sample is None else self._next_sample) + self.sample_s
        if w >= self._next_progress:
            self.progress(now, runner, w)
            self._next_progress = w + PROGRESS_EVERY_S

    def _throttle(self, runner: Any) -> None:
        if self.status_hz is None or self.status_hz >= runner.config.tick_hz:
            return
        for a in runner.agents:
            if a.bus is not None:
                a.bus = _ThrottledBus(a.bus, 1.0 / self.status_hz)
        self._throttled = True

    def sample(self, now: float, runner: Any, wall: float) -> None:
        """Record one sample of every time series at simulated time ``now``."""
        st = runner.coordinator.state if runner.coordinator is not None else None
        counts = dict.fromkeys(STATES, 0)
        dt = None if self._t_last_sample is None else now - self._t_last_sample
        n_wait = 0
        xmin, _, ymin, _ = self.extent
        for a in runner.agents:
            rec = a.last_status
            if rec is None:
                counts["idle"] += 1
                continue
            dead = st is not None and a.name in st.robots and not st.robots[a.name].alive
            state = "dead" if dead else ("stuck" if rec.stuck else str(rec.mode))
            counts[state if state in counts else "idle"] += 1
            if rec.pose is None:
                continue
            x, y = float(rec.pose[0]), float(rec.pose[1])
            prev = self._prev.get(a.name)
            self._prev[a.name] = (x, y)
            driving = rec.mode in DRIVING_MODES and not dead
            if driving:
                self.drivers.add(a.name)
            slow = (
                driving
                and dt is not None
                and dt > 0
                and prev is not None
                and math.hypot(x - prev[0], y - prev[1]) / dt < WAIT_SPEED_MPS
            )
            if rec.stuck or slow:
                n_wait += 1
                if dt is not None:
                    self.wait_robot_s += dt
                i = int((y - ymin) // HEAT_BIN_M)
                j = int((x - xmin) // HEAT_BIN_M)
                if 0 <= i < self.ny and 0 <= j < self.nx:
                    self.heat[i, j] += 1
        laps = (
            st.laps_completed()
            if st is not None
            else sum(int(a.last_status.laps) for a in runner.agents if a.last_status)
        )
        coll = runner.world.collisions() if runner.world is not None else None
        self.t.append(round(float(now), 3))
        self.wall.append(round(wall - self._wall0, 3))
        self.laps.append(int(laps))
        self.waiting.append(n_wait)
        self.collisions.append(int(coll or 0))
        self.deadlocks.append(int(st.deadlocks) if st is not None else 0)
        for s in STATES:
            self.states[s].append(counts[s])
        self._t_last_sample = now

    def progress(self, now: float, runner: Any, wall: float) -> None:
        """Print one progress line: sim time, x real time, laps, collisions, deadlocks, states."""
        out = self.out or sys.stdout
        loop_wall = wall - (self._loop_wall0 or wall)
        rtf = (now - self._loop_t0) / loop_wall if loop_wall > 0 else 0.0
        st = runner.coordinator.state if runner.coordinator is not None else None
        laps = st.laps_completed() if st is not None else 0
        coll = runner.world.collisions() if runner.world is not None else None
        dl = st.deadlocks if st is not None else 0
        states = ", ".join(
            f"{s} {self.states[s][-1]}" for s in STATES if self.states[s] and self.states[s][-1]
        )
        print(
            f"[loadtest t={now:8.1f} s sim, {wall - self._wall0:7.1f} s wall, {rtf:5.2f}x real time] "
            f"{laps} laps, {coll or 0} collisions, {dl} deadlocks; {states}",
            file=out,
            flush=True,
        )

    def series(self) -> dict[str, Any]:
        """The time series as JSON-ready lists (one entry per sample)."""
        n = max(self.n_robots, 1)
        tput: list[float] = []
        window: list[float] = []
        t0 = self.t[0] if self.t else 0.0
        for k, (t, laps) in enumerate(zip(self.t, self.laps, strict=True)):
            el = t - t0
            tput.append(round(laps / (n * el / 3600.0), 4) if el > 0 else 0.0)
            j = k
            while j > 0 and self.t[j - 1] >= t - THROUGHPUT_WINDOW_S - 1e-9:
                j -= 1
            span = t - self.t[j]
            window.append(round((laps - self.laps[j]) / (n * span / 3600.0), 4) if span > 0 else 0.0)
        return {
            "t_s": list(self.t),
            "wall_s": list(self.wall),
            "laps": list(self.laps),
            "throughput_laps_per_robot_hour": tput,
            "throughput_window_laps_per_robot_hour": window,
            "waiting": list(self.waiting),
            "collisions": list(self.collisions),
            "deadlocks": list(self.deadlocks),
            "states": {s: list(v) for s, v in self.states.items()},
        }

    def congestion(self, top: int = 10) -> dict[str, Any]:
        """The heat map's geometry and its ``top`` busiest cells (``[x, y, samples]``, cell centers)."""
        xmin, _, ymin, _ = self.extent
        flat = np.argsort(self.heat, axis=None)[::-1][:top]
        hot = []
        for f in flat:
            i, j = divmod(int(f), self.nx)
            c = int(self.heat[i, j])
            if c <= 0:
                break
            hot.append([round(xmin + (j + 0.5) * HEAT_BIN_M, 2), round(ymin + (i + 0.5) * HEAT_BIN_M, 2), c])
        return {
            "bin_m": HEAT_BIN_M,
            "extent": [float(v) for v in self.extent],
            "shape": [self.ny, self.nx],
            "waiting_robot_samples": int(self.heat.sum()),
            "hotspots": hot,
        }


def loadtest_block(
    report: Any, sampler: FleetSampler, *, backend: str, tick_hz: float, status_hz: float, step_s: float
) -> dict[str, Any]:
    """The ``loadtest`` block of the report (fields :data:`LOADTEST_FIELDS`).

    ``real_time_factor`` is simulated seconds per wall second of the loop (setup excluded:
    warehouse loading, Zenoh, world and agent creation, reported as ``setup_wall_s``);
    ``throughput_laps_per_robot_hour`` = laps / (robots x simulated hours);
    ``throughput_laps_per_patrolling_robot_hour`` = laps / hours spent in ``patrol`` (sampled,
    summed over robots: idle spares left out); ``mean_wait_s`` =
    simulated seconds spent waiting (see the module docstring) per robot that drove at all.
    """
    setup = sampler.setup_wall_s if sampler.setup_wall_s is not None else 0.0
    loop_wall = max(report.wall_time_s - setup, 1e-9)
    hours = report.robots * report.sim_time_s / 3600.0
    drivers = len(sampler.drivers)
    ts, patrol = sampler.t, sampler.states["patrol"]
    patrol_h = sum(patrol[k - 1] * (ts[k] - ts[k - 1]) for k in range(1, len(ts))) / 3600.0
    return {
        "backend": backend,
        "traffic": report.traffic is not None,
        "tick_hz": float(tick_hz),
        "status_hz": float(status_hz),
        "step_s": float(step_s),
        "sample_s": float(sampler.sample_s),
        "real_time_factor": round(report.sim_time_s / loop_wall, 3),
        "real_time_factor_overall": round(report.sim_time_s / max(report.wall_time_s, 1e-9), 3),
        "setup_wall_s": round(setup, 3),
        "throughput_laps_per_robot_hour": round(report.laps_completed / hours, 4) if hours > 0 else 0.0,
        "throughput_laps_per_patrolling_robot_hour": round(report.laps_completed / patrol_h, 4)
        if patrol_h > 0
        else 0.0,
        "mean_wait_s": round(sampler.wait_robot_s / drivers, 3) if drivers else None,
        "robots_that_drove": drivers,
        "series": sampler.series(),
        "congestion": sampler.congestion(),
        "plots": {},
    }


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
    from fleet.runner import BACKENDS, FleetRunner, register_backend

    stream = out or sys.stdout
    src = "fleet loadtest"
    for name, val in (("--tick-hz", tick_hz), ("--status-hz", status_hz), ("--sample-s", sample_s)):
        if not (math.isfinite(val) and val > 0):
            raise ConfigError(src, name, f"must be a positive number, got {val}")
    if backend == "sumo" and "sumo" not in BACKENDS:
        from sim.sumo_backend import SumoRunnerWorld

        register_backend("sumo", SumoRunnerWorld)
    if backend not in BACKENDS:
        raise ConfigError(
            src, "--backend", f"unknown backend {backend!r}; known: {', '.join(sorted(BACKENDS))}"
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
    from fleet.loadtest_plots import plot_congestion, plot_states, plot_throughput

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


# ---------------------------------------------------------------------------- command line

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

defaults for large fleets: agents tick at 2 Hz (--tick-hz) and publish their status at 1 Hz
(--status-hz); the config's agent.tick_hz is 10. Both are written to the report.
exit codes: 0 ok, 2 bad usage / bus or backend error, 130 interrupted (report still written)
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``fleet loadtest`` (see ``docs/performance.md``)."""
    p.add_argument("--robots", "-n", type=positive_int, required=True, metavar="N", help="number of robots")
    p.add_argument(
        "--duration", "-d", type=positive_float, required=True, metavar="S", help="simulated seconds to run"
    )
    p.add_argument("--backend", default="sim", metavar="NAME", help="sim (default) or sumo")
    p.add_argument(
        "--traffic", action="store_true", help="reservation-based traffic management (docs/traffic.md)"
    )
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
        help="up to K robots patrol each generated route (default: enough for half the fleet, "
        f"at most one robot per {PATROL_SPACING_M:g} m of the shortest loop)",
    )
    p.add_argument("--seed", type=int, default=1, help="warehouse and simulator seed (default 1)")
    p.add_argument("--endpoint", metavar="EP", help="Zenoh endpoint to listen on (default: a free port)")
    p.add_argument("--dpi", type=positive_int, default=100, help="PNG resolution (default 100)")


def add_loadtest_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``loadtest`` to ``fleet``'s subparsers; its handler is ``args.loadtest_handler``."""
    p = subparsers.add_parser(
        "loadtest",
        help="load-test the fleet with N robots: report JSON and plots",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    p.set_defaults(loadtest_handler=run_from_args)
    return p


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet loadtest",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Run the load test parsed into ``args``; print the summary; return the exit code."""
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
    )
    lt = res.data["loadtest"]
    r = res.report
    print(
        f"{'interrupted' if r.interrupted else 'finished'}: {r.robots} robots, {r.sim_time_s:.1f} s simulated in "
        f"{r.wall_time_s:.1f} s wall (setup {lt['setup_wall_s']:.1f} s, loop {lt['real_time_factor']:.2f}x real time)"
    )
    print(
        f"patrols: {r.patrols_assigned} assigned, {r.patrols_completed} completed, {r.laps_completed} laps "
        f"({lt['throughput_laps_per_robot_hour']:.2f} per robot-hour, "
        f"{lt['throughput_laps_per_patrolling_robot_hour']:.2f} per patrolling robot-hour)"
    )
    wait = lt["mean_wait_s"]
    print(
        f"collisions: {r.collisions}   deadlocks: {r.deadlocks}   reassignments: {r.reassignments}   "
        f"mean wait: {'n/a' if wait is None else f'{wait:.1f} s'} per driving robot"
    )
    print(f"report: {res.report_path}")
    for p in res.plots.values():
        print(f"plot: {p}")
    return 130 if res.interrupted else 0


def loadtest_main(argv: Sequence[str] | None = None) -> int:
    """``fleet loadtest`` as a function: 0 ok, 2 bad usage or setup error, 130 interrupted."""
    try:
        args = build_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    except SystemExit as e:  # argparse: --help (0) or bad usage (2), message already printed
        return int(e.code) if isinstance(e.code, int) else 2
    try:
        return run_from_args(args)
    except (ConfigError, BusError, BackendError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


__all__ = [
    "DEFAULT_STATUS_HZ",
    "DEFAULT_TICK_HZ",
    "FleetSampler",
    "LoadTestResult",
    "add_loadtest_parser",
    "build_parser",
    "loadtest_block",
    "loadtest_main",
    "prepare_config",
    "run_loadtest",
]


if __name__ == "__main__":
    sys.exit(loadtest_main())
