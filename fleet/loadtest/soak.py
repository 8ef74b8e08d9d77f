"""Soak runs: does a long run's memory stay flat?

:func:`run_soak` runs a load-test fleet (:func:`fleet.loadtest.run.prepare_config`: a generated
warehouse, every robot's agent and the coordinator in one process, traffic management on by
default) as fast as it goes for ``duration`` simulated seconds and samples the process's
resident set size (RSS, from ``/proc/self/status``) every ``every_s`` simulated seconds through
the runner's ``observers`` hook (while the fleet runs; the RSS once the report is built is
kept apart, :attr:`SoakResult.report_mb`). :class:`SoakResult` says how much RSS grew after the warm-up
(the first ``warmup`` fraction of the run, when the trees, the traffic tables and the
simulator's bounded histories fill up): :attr:`SoakResult.growth` is the highest sample after
the warm-up over the sample at its end, minus one.

Nothing here prints; ``bench/soak.py`` prints the samples and the figures
(``docs/performance.md``). Units: simulated seconds unless a name says ``wall``; MB = 2^20 bytes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from fleet.errors import ConfigError
from fleet.loadtest.memory import rss_mb

if TYPE_CHECKING:
    from fleet.runtime.report import RunReport
    from fleet.runtime.runner import FleetRunner

#: Default share of the run counted as warm-up.
DEFAULT_WARMUP = 0.25


@dataclass(frozen=True)
class RssSample:
    """RSS ``rss_mb`` (MB) at simulated time ``t`` (s from the run's start), ``wall_s`` into the
    run; ``laps`` the fleet had completed by then (-1: no coordinator here)."""

    t: float
    wall_s: float
    rss_mb: float
    laps: int = -1


@dataclass
class SoakResult:
    """The samples of one soak run, its warm-up share and its report."""

    robots: int
    duration_s: float
    warmup: float
    samples: list[RssSample] = field(default_factory=list)
    report: RunReport | None = None
    #: RSS once the run's report is built (MB): the end of the run, not its steady state.
    report_mb: float = float("nan")

    def after_warmup(self) -> list[RssSample]:
        """The samples from the end of the warm-up on (the first is the baseline)."""
        t_warm = self.warmup * self.duration_s
        return [s for s in self.samples if s.t >= t_warm - 1e-9]

    @property
    def baseline_mb(self) -> float:
        """RSS at the end of the warm-up (MB)."""
        after = self.after_warmup()
        return after[0].rss_mb if after else float("nan")

    @property
    def growth(self) -> float:
        """Highest RSS after the warm-up over the baseline, minus one (0.05 = 5 % growth)."""
        after = self.after_warmup()
        if len(after) < 2:
            return float("nan")
        return max(s.rss_mb for s in after) / after[0].rss_mb - 1.0

    @property
    def growth_kb_per_sim_s(self) -> float:
        """Least-squares slope of RSS after the warm-up (kB per simulated second)."""
        after = self.after_warmup()
        if len(after) < 2:
            return float("nan")
        n = len(after)
        mt = sum(s.t for s in after) / n
        mr = sum(s.rss_mb for s in after) / n
        var = sum((s.t - mt) ** 2 for s in after)
        cov = sum((s.t - mt) * (s.rss_mb - mr) for s in after)
        return 1024.0 * cov / var if var > 0 else 0.0


def run_soak(
    n_robots: int,
    duration: float,
    out_dir: str | Path,
    *,
    every_s: float = 60.0,
    warmup: float = DEFAULT_WARMUP,
    traffic: bool = True,
    seed: int = 1,
    on_sample: Callable[[RssSample], None] | None = None,
) -> SoakResult:
    """Run ``n_robots`` for ``duration`` simulated seconds (the warehouse goes to ``out_dir``)
    and sample RSS every ``every_s`` simulated seconds (``on_sample`` gets each sample).
    Raises :class:`~fleet.errors.ConfigError` for a non-positive duration or period, or a
    warm-up share outside [0, 1)."""
    from fleet.bus.session import free_endpoint
    from fleet.loadtest.run import prepare_config
    from fleet.runtime.runner import FleetRunner
    from fleet.viz.display import NullDisplay

    src = "soak"
    if not duration > 0 or not every_s > 0:
        raise ConfigError(src, "duration", f"duration and period must be positive, got {duration}, {every_s}")
    if not 0.0 <= warmup < 1.0:
        raise ConfigError(src, "warmup", f"must be in [0, 1), got {warmup}")
    cfg = prepare_config(n_robots, out_dir, seed=seed)
    result = SoakResult(len(cfg.robots), float(duration), float(warmup))
    runner = FleetRunner(
        cfg,
        duration=duration,
        speed=0.0,
        endpoint=free_endpoint(),
        live=False,
        display=NullDisplay(),
        traffic=traffic,
    )
    wall0 = time.monotonic()
    t0: list[float] = []
    next_t = [0.0]

    def sample(now: float, run: FleetRunner) -> None:
        if not t0:
            t0.append(now)
        t = now - t0[0]
        if t + 1e-9 < next_t[0]:
            return
        next_t[0] = t + every_s
        st = run.coordinator.state if run.coordinator is not None else None
        s = RssSample(t, time.monotonic() - wall0, rss_mb(), st.laps_completed() if st is not None else -1)
        result.samples.append(s)
        if on_sample is not None:
            on_sample(s)

    runner.observers.append(sample)
    result.report = runner.run()
    result.report_mb = rss_mb()
    return result
