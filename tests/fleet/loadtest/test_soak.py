"""Soak: 200 robots with traffic management for 30 simulated minutes in one process (real
simulator, real Zenoh on loopback, real py_trees): the process's RSS after the warm-up (the
first quarter of the run) stays within :data:`MAX_GROWTH` of its value at the end of the
warm-up. And a fleet that keeps driving (100 robots without traffic management, so that
nobody jams: hundreds of laps, thousands of goals): its memory must not grow with the work
done either (it did, 14.5 % over an hour at 200 robots, while the simulator's plan cache and
goal book grew with every goal). ``scale`` marker (``make test-scale``); ``bench/soak.py`` prints the same samples
(figures in ``docs/performance.md``, "Soak").

The bound is not 0: bounded histories still fill early in the run (the simulator keeps the
last ten minutes of every robot's trajectory, float32, about 1.3 kB per simulated second for
200 robots; the coordinator's event log up to 10,000 lines). Measured with ``bench/soak.py``
on this workload: 3.2 % after the warm-up over 30 minutes, 1.4 % over an hour (15.8 % over an hour while the
simulator kept a whole hour of trajectories); the moving fleet: see docs/performance.md."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.loadtest.soak import run_soak

#: Most RSS may grow after the warm-up (0.10 = 10 %, the issue's bound; see the module docstring).
MAX_GROWTH = 0.10


@pytest.mark.scale
@pytest.mark.timeout(3600)  # hang guard: about 5 min on an idle 2-core machine
def test_rss_stays_flat_over_30_simulated_minutes_of_200_robots(tmp_path: Path) -> None:
    r = run_soak(200, 1800.0, tmp_path, every_s=60.0)
    assert r.report is not None and r.report.sim_time_s >= 1800.0 - 1.0
    assert len(r.after_warmup()) >= 20
    curve = [(round(s.t), round(s.rss_mb)) for s in r.samples]
    assert r.growth < MAX_GROWTH, f"RSS grew {100 * r.growth:.1f} % after the warm-up: {curve}"


@pytest.mark.scale
@pytest.mark.timeout(2400)  # hang guard: about 2 min on an idle 2-core machine
def test_rss_stays_flat_while_100_robots_keep_driving_for_30_simulated_minutes(tmp_path: Path) -> None:
    r = run_soak(100, 1800.0, tmp_path, every_s=60.0, traffic=False)
    assert r.report is not None and r.report.sim_time_s >= 1800.0 - 1.0
    assert r.report.laps_completed >= 300, "the fleet must keep driving for this soak to mean anything"
    assert len(r.after_warmup()) >= 20
    curve = [(round(s.t), round(s.rss_mb)) for s in r.samples]
    assert r.growth < MAX_GROWTH, f"RSS grew {100 * r.growth:.1f} % after the warm-up: {curve}"
