"""FleetRunner: the loop (ticks at tick_hz of simulated time, pacing with the one Pacer),
pluggable backends, status on the bus at bus.status_hz, diagnostics through logging, and the
Zenoh session always closed (normal end, stop(), Ctrl-C, errors)."""

from __future__ import annotations

import dataclasses
import logging
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint

import fleet.runtime.runner as runner_module
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.clock import Pacer
from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.errors import BackendError, BusError, ConfigError
from fleet.messages import StatusRecord
from fleet.navigation import Clock
from fleet.runtime.agent import RobotAgent
from fleet.runtime.backends import BACKENDS, register_backend
from fleet.runtime.runner import FleetRunner
from fleet.runtime.worlds import SimWorld
from fleet.viz.display import FleetSnapshot, NullDisplay

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


def assert_endpoint_free(ep: str) -> None:
    """The runner's session is closed: the endpoint can be listened on again."""
    s = open_session(ep, "router")
    s.close()


@pytest.fixture(scope="module")
def config() -> FleetConfig:
    return load_config(PATROL, robots=3)


def test_short_run_ticks_agents_and_assigns(config: FleetConfig) -> None:
    ep = free_endpoint()
    runner = FleetRunner(config, duration=10.0, speed=0, endpoint=ep, live=False)
    report = runner.run()
    assert report.sim_time_s == pytest.approx(10.0, abs=config.sim.step_s)
    assert not report.interrupted
    assert all(a.ticks == 100 for a in runner.agents)  # 10 Hz of simulated time
    assert report.patrols_assigned == 3 and report.robots == 3
    assert [r.name for r in report.per_robot] == ["robot1", "robot2", "robot3"]
    assert all(r.final_state == "patrol" and r.distance_m > 1.0 for r in report.per_robot)
    assert set(report.trajectories) == {"robot1", "robot2", "robot3"}
    assert_endpoint_free(ep)


class FakeWall:
    """A wall clock that moves only when slept on."""

    def __init__(self) -> None:
        self.t = 0.0
        self.slept: list[float] = []

    def now(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s


def test_speed_paces_simulated_time_with_the_pacer(
    config: FleetConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """speed 4: the loop's pacer sleeps until the wall clock has moved a quarter of the
    simulated time (on a wall clock that moves only when slept on, exactly that)."""
    made: list[tuple[float, FakeWall]] = []

    class RecordingPacer(Pacer):
        def __init__(self, clock: Clock, speed: float, wall: Clock | None = None) -> None:
            fake = FakeWall()
            made.append((speed, fake))
            super().__init__(clock, speed, fake)

        def wait(self, sleep: Callable[[float], None] | None = None) -> None:
            super().wait(made[-1][1].sleep)

    monkeypatch.setattr(runner_module, "Pacer", RecordingPacer)
    report = FleetRunner(
        config, duration=2.0, speed=4.0, endpoint=free_endpoint(), display=NullDisplay()
    ).run()
    ((speed, wall),) = made
    assert speed == 4.0 and report.sim_time_s == pytest.approx(2.0, abs=config.sim.step_s)
    assert wall.t == pytest.approx(report.sim_time_s / 4.0, abs=1e-6)
    assert len(wall.slept) == round(2.0 / config.sim.step_s)  # one wait per step


def test_stop_from_another_thread_ends_a_paced_wait_and_closes_everything(config: FleetConfig) -> None:
    """speed 0.001 (a step every 50 wall seconds): stop() from another thread ends the run at
    once, in the middle of the pacer's wait."""
    ep = free_endpoint()
    runner = FleetRunner(config, duration=None, speed=0.001, endpoint=ep, display=NullDisplay())
    first_tick = threading.Event()
    runner.observers.append(lambda now, r: first_tick.set())

    def stop_after_the_first_tick() -> None:
        if first_tick.wait(120):
            runner.stop()

    stopper = threading.Thread(target=stop_after_the_first_tick)
    stopper.start()
    report = runner.run()
    stopper.join(10)
    assert report.interrupted and report.sim_time_s == pytest.approx(config.sim.step_s)
    assert report.wall_time_s < 40.0  # far less than the 50 s the step's wait would take
    assert_endpoint_free(ep)


def test_ctrl_c_in_the_loop_closes_the_session(config: FleetConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    ep = free_endpoint()
    runner = FleetRunner(config, duration=30.0, speed=0, endpoint=ep, live=False)
    calls = {"n": 0}
    orig = SimWorld.advance

    def advance(self: SimWorld) -> None:
        calls["n"] += 1
        if calls["n"] == 50:
            raise KeyboardInterrupt
        orig(self)

    monkeypatch.setattr(SimWorld, "advance", advance)
    report = runner.run()
    assert report.interrupted and report.sim_time_s < 5.0
    assert_endpoint_free(ep)


def test_error_in_the_loop_still_closes_the_session(
    config: FleetConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    ep = free_endpoint()
    runner = FleetRunner(config, duration=30.0, speed=0, endpoint=ep, live=False)

    def boom(self: SimWorld) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(SimWorld, "advance", boom)
    with pytest.raises(RuntimeError):
        runner.run()
    assert_endpoint_free(ep)


def test_port_in_use_raises_bus_error(config: FleetConfig) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        ep = f"tcp/127.0.0.1:{s.getsockname()[1]}"
        with pytest.raises(BusError):
            FleetRunner(config, duration=1.0, speed=0, endpoint=ep, live=False).run()


def test_backends_are_pluggable_by_name(config: FleetConfig) -> None:
    made: list[str] = []

    def factory(cfg: FleetConfig, robots: list[Any], session: Any) -> SimWorld:
        made.append(cfg.name)
        return SimWorld(cfg, robots, session)

    register_backend("test-sim", factory)
    try:
        report = FleetRunner(
            config, duration=1.0, speed=0, endpoint=free_endpoint(), live=False, backend="test-sim"
        ).run()
        assert made == [config.name] and report.backend == "test-sim"
    finally:
        BACKENDS.pop("test-sim", None)
    with pytest.raises(ConfigError, match="unknown backend"):
        FleetRunner(config, backend="nope")


def test_agents_subset_and_no_coordinator(config: FleetConfig) -> None:
    runner = FleetRunner(
        config,
        duration=2.0,
        speed=0,
        endpoint=free_endpoint(),
        live=False,
        agents=["robot2"],
        coordinator=False,
    )
    report = runner.run()
    assert [a.name for a in runner.agents] == ["robot2"]
    assert report.patrols_assigned == 0
    assert [r.name for r in report.per_robot] == ["robot2"]
    with pytest.raises(ConfigError, match="robot9"):
        FleetRunner(config, agents=["robot9"])


def test_core_import_does_not_pull_ros_or_sumo() -> None:
    import subprocess
    import sys

    code = "import sys, fleet.runtime.runner, fleet.cli, fleet.coordination.coordinator, fleet.runtime.agent; " \
        "print([m for m in ('rclpy', 'libsumo', 'traci') if m in sys.modules])"  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "[]", out.stderr


def test_in_process_runs_are_reproducible(config: FleetConfig) -> None:
    """speed 0, same config: the same run (agents and coordinator do not depend on bus timing)."""
    reports = [
        FleetRunner(config, duration=60.0, speed=0, endpoint=free_endpoint(), live=False).run()
        for _ in range(2)
    ]
    a, b = (r.to_dict() for r in reports)
    for d in (a, b):
        d.pop("wall_time_s")
    assert a == b


def test_status_hz_limits_the_bus_not_the_coordinator(
    config: FleetConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """bus.status_hz 2 with agents at 10 Hz: each robot publishes 1 status in 5 ticks on the bus;
    the in-process coordinator still gets every tick's status, so the run is the same run."""
    published: list[StatusRecord] = []
    orig = StatusBus.publish_status

    def count(self: StatusBus, rec: StatusRecord) -> None:
        published.append(rec)
        orig(self, rec)

    monkeypatch.setattr(StatusBus, "publish_status", count)
    reports = {}
    for hz in (None, 2.0):
        published.clear()
        cfg = dataclasses.replace(config, status_hz=hz)
        runner = FleetRunner(cfg, duration=20.0, speed=0, endpoint=free_endpoint(), display=NullDisplay())
        reports[hz] = runner.run().to_dict()
        ticks = runner.agents[0].ticks
        assert ticks == 200
        per_robot = {a.name: sum(1 for r in published if r.robot == a.name) for a in runner.agents}
        expect = ticks if hz is None else ticks // 5
        assert per_robot == dict.fromkeys(per_robot, expect), per_robot
        assert all(a.published == expect for a in runner.agents)
        if hz is not None:  # 2 Hz of simulated time: records 0.5 s apart
            times = [r.t for r in published if r.robot == "robot1"]
            assert all(b - a == pytest.approx(0.5) for a, b in zip(times, times[1:], strict=False))
    for d in reports.values():
        d.pop("wall_time_s")
    assert reports[None] == reports[2.0]


def test_in_process_runs_keep_no_bus_trajectories(config: FleetConfig) -> None:
    """The simulator records the local robots' trajectories: the runner keeps none of its own."""
    runner = FleetRunner(config, duration=10.0, speed=0, endpoint=free_endpoint(), display=NullDisplay())
    report = runner.run()
    assert all(len(t) >= 10 for t in report.trajectories.values())
    assert runner.bus_view.trajectory_bytes() == 0 and set(runner.bus_view.latest()) == {
        "robot1",
        "robot2",
        "robot3",
    }


def test_a_backend_error_ends_the_run_with_a_warning_and_a_report(
    config: FleetConfig, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    calls = {"n": 0}
    orig = SimWorld.advance

    def advance(self: SimWorld) -> None:
        calls["n"] += 1
        if calls["n"] == 40:
            raise BackendError("the simulator went away")
        orig(self)

    def close(self: RobotAgent) -> None:
        raise RuntimeError("token already gone")

    monkeypatch.setattr(SimWorld, "advance", advance)
    monkeypatch.setattr(RobotAgent, "close", close)
    ep = free_endpoint()
    with caplog.at_level(logging.WARNING, logger="fleet"):
        report = FleetRunner(config, duration=30.0, speed=0, endpoint=ep, display=NullDisplay()).run()
    assert report.interrupted and report.sim_time_s == pytest.approx(39 * config.sim.step_s)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert "the simulator went away; ending the run" in warnings
    assert [w for w in warnings if w.startswith("closing agent")] == [
        f"closing agent robot{i}: token already gone" for i in (1, 2, 3)
    ]
    assert_endpoint_free(ep)


def test_the_display_sees_the_fleet(config: FleetConfig) -> None:
    shown: list[FleetSnapshot] = []
    closed: list[FleetSnapshot | None] = []

    class Recorder:
        interval_s = 0.0

        def show(self, snap: FleetSnapshot) -> None:
            shown.append(snap)

        def close(self, final: FleetSnapshot | None = None) -> None:
            closed.append(final)

    FleetRunner(config, duration=5.0, speed=0, endpoint=free_endpoint(), display=Recorder()).run()
    assert len(shown) == round(5.0 / config.sim.step_s)  # every iteration with interval 0
    (final,) = closed
    assert final is not None and final.sim_time_s == pytest.approx(5.0) and final.duration_s == 5.0
    assert [r.robot for r in final.records] == ["robot1", "robot2", "robot3"]
    assert final.alive == {"robot1", "robot2", "robot3"} and final.laps == 0
