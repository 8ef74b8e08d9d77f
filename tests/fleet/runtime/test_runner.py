"""FleetRunner: the loop (ticks at tick_hz of simulated time, pacing), pluggable backends,
and the Zenoh session always closed (normal end, stop(), Ctrl-C, errors)."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.errors import BusError, ConfigError
from fleet.runtime.backends import BACKENDS, register_backend
from fleet.runtime.runner import FleetRunner
from fleet.runtime.worlds import SimWorld

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


def test_speed_paces_simulated_time(config: FleetConfig) -> None:
    runner = FleetRunner(config, duration=2.0, speed=4.0, endpoint=free_endpoint(), live=False)
    report = runner.run()
    assert report.wall_time_s >= 0.45


def test_stop_from_another_thread_closes_everything(config: FleetConfig) -> None:
    ep = free_endpoint()
    runner = FleetRunner(config, duration=None, speed=1.0, endpoint=ep, live=False)
    threading.Timer(1.0, runner.stop).start()
    report = runner.run()
    assert report.interrupted and 0.5 < report.sim_time_s < 3.0
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
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "[]", out.stderr
    assert time.monotonic() > 0


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
