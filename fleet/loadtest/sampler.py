"""Sampling a running fleet for a load test: laps, robots per state, waiting robots and the
congestion heat map over simulated time."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from fleet.types import DRIVING_MODES
from fleet.viz.display import FleetSnapshot

if TYPE_CHECKING:
    from fleet.coordination.coordinator import CoordinatorState
    from fleet.runtime.report import RunReport
    from fleet.runtime.runner import FleetRunner

#: Default sampling period of the time series (simulated seconds).
DEFAULT_SAMPLE_S = 5.0


#: Throughput is also reported over a sliding window of this many simulated seconds.
THROUGHPUT_WINDOW_S = 60.0


#: A robot in a driving mode slower than this on average between two samples is waiting (m/s).
WAIT_SPEED_MPS = 0.1


#: Cell size of the congestion heat map (m).
HEAT_BIN_M = 1.0


#: Progress lines are printed this often (wall seconds).
PROGRESS_EVERY_S = 5.0


#: Robot states in the ``states`` time series, in plotting order.
STATES = ("patrol", "picking", "recovery", "charging", "idle", "stuck", "dead")


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


def run_deadlocks(runner: FleetRunner) -> int:
    """The run's deadlock count as its report gives it: with traffic management the traffic
    manager's wait-for-cycle episodes, else the coordinator's count of robots stuck beside
    another (the progress lines once showed the latter while the report gave the former)."""
    policy = runner.traffic_policy
    if policy is not None:
        return int(policy.deadlocks)
    st = runner.coordinator.state if runner.coordinator is not None else None
    return int(st.deadlocks) if st is not None else 0


@dataclass
class FleetSampler:
    """The runner observer of a load test: samples the fleet every ``sample_s`` simulated
    seconds and hands a progress snapshot to ``on_progress`` every :data:`PROGRESS_EVERY_S`
    wall seconds. See :mod:`fleet.loadtest.run` for the metrics.

    ``extent`` is the map's ``(xmin, xmax, ymin, ymax)`` (m); ``n_robots`` normalizes the
    throughput (laps per robot-hour over every robot of the fleet).
    """

    n_robots: int
    extent: tuple[float, float, float, float]
    sample_s: float = DEFAULT_SAMPLE_S
    on_progress: Callable[[FleetSnapshot], None] | None = None
    t: list[float] = field(default_factory=list)
    wall: list[float] = field(default_factory=list)
    laps: list[int] = field(default_factory=list)
    waiting: list[int] = field(default_factory=list)
    collisions: list[int] = field(default_factory=list)
    deadlocks: list[int] = field(default_factory=list)
    states: dict[str, list[int]] = field(default_factory=lambda: {s: [] for s in STATES})
    wait_robot_s: float = 0.0
    setup_wall_s: float | None = None
    #: CPU seconds of this process (all threads) from the loop's first period to its last.
    loop_cpu_s: float = 0.0

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
        self._cpu0 = 0.0
        self._loop_t0 = 0.0
        self._next_progress = 0.0

    def start(self) -> None:
        """Mark the wall-clock start of the run (before the runner sets up)."""
        self._wall0 = time.monotonic()

    def __call__(self, now: float, runner: FleetRunner) -> None:
        w = time.monotonic()
        cpu = time.process_time()
        if self._loop_wall0 is None:
            self._cpu0 = cpu
            self._loop_wall0 = w
            self._loop_t0 = now
            self.setup_wall_s = w - self._wall0
            self._next_progress = w + PROGRESS_EVERY_S
        self.loop_cpu_s = cpu - self._cpu0
        if self._next_sample is None or now >= self._next_sample - 1e-9:
            self.sample(now, runner, w)
            self._next_sample = (now if self._next_sample is None else self._next_sample) + self.sample_s
        if w >= self._next_progress:
            if self.on_progress is not None:
                self.on_progress(self.progress(now, runner, w))
            self._next_progress = w + PROGRESS_EVERY_S

    def sample(self, now: float, runner: FleetRunner, wall: float) -> None:
        """Record one sample of every time series at simulated time ``now``."""
        st: CoordinatorState | None = runner.coordinator.state if runner.coordinator is not None else None
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
            else sum(int(a.last_status.laps) for a in runner.agents if a.last_status is not None)
        )
        coll = runner.world.collisions() if runner.world is not None else None
        self.t.append(round(float(now), 3))
        self.wall.append(round(wall - self._wall0, 3))
        self.laps.append(int(laps))
        self.waiting.append(n_wait)
        self.collisions.append(int(coll or 0))
        self.deadlocks.append(run_deadlocks(runner))
        for s in STATES:
            self.states[s].append(counts[s])
        self._t_last_sample = now

    def progress(self, now: float, runner: FleetRunner, wall: float) -> FleetSnapshot:
        """The progress now: sim time, x real time, laps, collisions, deadlocks, robots per state
        (as of the last sample)."""
        loop_wall = wall - (self._loop_wall0 or wall)
        st = runner.coordinator.state if runner.coordinator is not None else None
        coll = runner.world.collisions() if runner.world is not None else None
        return FleetSnapshot(
            sim_time_s=now,
            wall_s=wall - self._wall0,
            duration_s=runner.duration,
            laps=st.laps_completed() if st is not None else 0,
            collisions=coll or 0,
            deadlocks=run_deadlocks(runner),
            states={s: self.states[s][-1] for s in STATES if self.states[s]},
            real_time_factor=(now - self._loop_t0) / loop_wall if loop_wall > 0 else 0.0,
            label="loadtest",
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
    report: RunReport, sampler: FleetSampler, *, backend: str, tick_hz: float, status_hz: float, step_s: float
) -> dict[str, Any]:
    """The ``loadtest`` block of the report (fields :data:`LOADTEST_FIELDS`).

    ``real_time_factor`` is simulated seconds per wall second of the loop (setup excluded:
    warehouse loading, Zenoh, world and agent creation, reported as ``setup_wall_s``);
    ``sim_s_per_cpu_s`` simulated seconds per CPU second the process spent in the loop
    (``loop_cpu_s``, all its threads): the real-time factor it would reach with a core of its
    own, which a loaded machine does not hide;
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
        "loop_cpu_s": round(sampler.loop_cpu_s, 3),
        "sim_s_per_cpu_s": round(report.sim_time_s / sampler.loop_cpu_s, 3)
        if sampler.loop_cpu_s > 0
        else None,
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
