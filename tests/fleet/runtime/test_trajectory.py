"""Bounded trajectories: a run of any length keeps at most ``max_points`` samples per robot,
spread over the whole run; the bus view keeps the latest status of every robot and no
trajectory for robots whose world records them."""

from __future__ import annotations

import msgspec
import pytest
from bus_peer import record

from fleet.runtime.trajectory import BusView, Trajectory


def test_samples_are_spaced_by_the_period() -> None:
    tr = Trajectory(period_s=0.5, max_points=100)
    added = [tr.add(0.1 * k, float(k), 0.0) for k in range(20)]
    assert sum(added) == 4 and len(tr) == 4
    assert [x for _, x, _ in tr.points()] == [0.0, 5.0, 10.0, 15.0]
    assert [t for t, _, _ in tr.points()] == pytest.approx([0.0, 0.5, 1.0, 1.5])


def test_a_long_trajectory_stays_bounded_and_covers_the_whole_run() -> None:
    tr = Trajectory(period_s=0.5, max_points=64)
    for k in range(100_000):  # 50 000 s at 2 samples per second
        tr.add(0.5 * k, float(k), 2.0)
        assert len(tr) <= 64
    pts = tr.points()
    assert 32 <= len(pts) <= 64
    assert pts[0][0] == 0.0 and pts[-1][0] >= 50_000 - 2 * tr.period_s  # first and recent samples
    gaps = {round(b[0] - a[0], 6) for a, b in zip(pts, pts[1:], strict=False)}
    assert gaps == {tr.period_s}  # evenly spaced after the decimations
    assert tr.nbytes <= 3 * 8 * 64 * 2  # the arrays' buffers, with their spare room


def test_bad_bounds() -> None:
    with pytest.raises(ValueError, match="max_points"):
        Trajectory(max_points=1)


def test_bus_view_memory_stays_flat_over_a_long_run() -> None:
    """50 robots reporting at 2 Hz: the trajectories' memory after 1 simulated hour is what it
    was after half an hour (it grew without bound before)."""
    view = BusView(period_s=0.5, max_points=256)
    recs = [record(f"robot{i}", i) for i in range(50)]
    sizes = []
    for minute in range(60):
        for k in range(120):
            t = minute * 60 + 0.5 * k
            for r in recs:
                view.see(msgspec.structs.replace(r, t=t, pose=(t % 30, 1.0, 0.0)))
        sizes.append(view.trajectory_bytes())
    assert sizes[-1] == sizes[29] and sizes[-1] <= 50 * 256 * 24 * 2
    assert 128 <= len(view.trajectory("robot7")) <= 256
    assert view.latest()["robot7"].t == pytest.approx(3599.5)


def test_bus_view_skips_the_robots_their_world_records() -> None:
    view = BusView()
    view.see(record("robot1", 1))
    view.see(record("robot2", 2))
    view.skip_trajectories(["robot1"])
    view.see(record("robot1", 30))
    assert view.trajectory("robot1") == [] and len(view.trajectory("robot2")) == 1
    assert set(view.latest()) == {"robot1", "robot2"} and view.latest()["robot1"].seq == 30
    view.see(msgspec.structs.replace(record("robot3", 3), pose=None))
    assert view.trajectory("robot3") == [] and "robot3" in view.latest()
