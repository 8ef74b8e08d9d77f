"""RobotAgent: orders applied to the robot's blackboard (duplicates and superseded ids
ignored), one tree tick + one status record per tick, the status published on the bus at
most at ``status_hz``, the liveliness token, all on real Zenoh, the real simulator and the
real tree."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from msgspec.structs import replace
from ports import free_endpoint

from fleet.bus.lease import LeaseWatch, acquire_coordinator_lease
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.messages import Grant, StatusRecord, TaskMessage
from fleet.runtime.agent import RobotAgent
from fleet.types import Pose2D
from sim.simulator import Simulator

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


@pytest.fixture(scope="module")
def config() -> FleetConfig:
    return load_config(PATROL, robots=2)


@pytest.fixture
def bus() -> Iterator[StatusBus]:
    session = open_session(free_endpoint(), "router")
    b = StatusBus(session)
    try:
        yield b
    finally:
        b.close()
        try:
            session.close()
        except Exception:  # noqa: BLE001 - the bus may have closed it
            pass


#: Hang guard of the waits on the bus (s): far more than loopback needs on a loaded machine.
WAIT_S = 30.0


def make_agent(
    config: FleetConfig, bus: Any, name: str = "robot1", **kw: Any
) -> tuple[RobotAgent, Simulator]:
    clock = SimClock()
    sim = Simulator(config.grid, config.sim, clock)
    for r in config.robots:
        sim.add_robot(r)
    spec = config.robot(name)
    agent = RobotAgent(
        spec.namespace, sim.backend(spec.namespace), clock, bus, battery_model=config.sim.battery, **kw
    )
    return agent, sim


class Handle:
    def undeclare(self) -> None:
        return None


class CountingBus:
    """A bus that only counts what is published (an :class:`~fleet.runtime.agent.AgentBus`)."""

    def __init__(self) -> None:
        self.statuses: list[StatusRecord] = []

    def publish_status(self, rec: StatusRecord) -> None:
        self.statuses.append(rec)

    def subscribe_tasks(self, robot: str, callback: Callable[[TaskMessage], None]) -> Handle:
        return Handle()

    def subscribe_grants(self, robot: str, callback: Callable[[Grant], None]) -> Handle:
        return Handle()

    def declare_alive(self, robot: str) -> Handle:
        return Handle()


def wait_until(
    pred: Callable[[], bool], what: str, timeout: float = WAIT_S, act: Callable[[], Any] | None = None
) -> None:
    """Poll ``pred`` (calling ``act`` before each check) until it holds; fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        if act is not None:
            act()
        threading.Event().wait(0.01)


def route(config: FleetConfig, name: str = "aisles_1_2") -> tuple[Pose2D, ...]:
    return config.route_poses(config.route(name))


def patrol_msg(
    config: FleetConfig, task_id: str, robot: str = "robot1", name: str = "aisles_1_2"
) -> TaskMessage:
    return TaskMessage(
        robot=robot, task_id=task_id, kind="patrol", route=name, poses=route(config, name),
        charger=config.chargers[0].pose,
    )  # fmt: skip


def run(agent: RobotAgent, sim: Simulator, seconds: float) -> None:
    steps_per_tick = round(0.1 / sim.params.step_s)
    for _ in range(int(seconds * 10)):
        agent.tick()
        for _ in range(steps_per_tick):
            sim.step()


def test_orders_applied_once_and_idle_clears(config: FleetConfig) -> None:
    agent, sim = make_agent(config, None)
    try:
        assert agent.apply(patrol_msg(config, "p-0001"))
        assert agent.bb.task_id == "p-0001" and agent.bb.route == route(config)
        assert agent.bb.charger == config.chargers[0].pose
        assert not agent.apply(patrol_msg(config, "p-0001"))  # duplicate
        assert agent.apply(patrol_msg(config, "p-0003", name="aisles_3_4"))
        assert not agent.apply(patrol_msg(config, "p-0001"))  # late copy of a superseded order
        assert agent.bb.task_id == "p-0003" and agent.bb.route == route(config, "aisles_3_4")
        assert not agent.apply(patrol_msg(config, "p-0004", robot="robot2"))  # not for this robot
        assert agent.apply(TaskMessage(robot="robot1", task_id="i-0005", kind="idle", charger=None))
        assert agent.bb.route is None and agent.bb.task_id is None
    finally:
        agent.close()


def test_tick_drives_the_route_and_reports_laps_for_the_current_id(config: FleetConfig) -> None:
    agent, sim = make_agent(config, None)
    try:
        rec = agent.tick()
        assert rec.robot == "robot1" and rec.mode == "idle" and rec.task_id is None and rec.seq == 1
        agent.deliver(patrol_msg(config, "p-0001", name="aisles_1_2"))
        run(agent, sim, 5.0)
        rec = agent.last_status
        assert rec.mode == "patrol" and rec.task_id == "p-0001" and rec.leaf
        assert rec.distance_m > 1.0 and rec.pose is not None
        assert rec.t == pytest.approx(sim.clock.now() - 0.1, abs=0.11)
        # laps counted only for the id they were driven under
        agent.bb.laps, agent.bb.lap_task_id = 3, "p-0000"
        assert agent.status().laps == 0
        agent.bb.lap_task_id = "p-0001"
        assert agent.status().laps == 3
    finally:
        agent.close()


def test_status_hz_limits_what_is_published_not_what_is_ticked(config: FleetConfig) -> None:
    """Ticking at 10 Hz with ``status_hz=2``: 1 record in 5 is published (0.5 s apart), every
    record goes to ``on_status``; without ``status_hz`` every record is published."""
    for hz, every in ((2.0, 5), (None, 1), (20.0, 1)):
        bus = CountingBus()
        fed: list[StatusRecord] = []
        agent, sim = make_agent(config, bus, status_hz=hz, on_status=fed.append)
        try:
            run(agent, sim, 5.0)
        finally:
            agent.close()
        assert len(fed) == 50 and agent.ticks == 50
        assert len(bus.statuses) == agent.published == 50 // every, hz
        assert [r.seq for r in bus.statuses] == [r.seq for r in fed][::every]
    with pytest.raises(ValueError, match="status_hz"):
        make_agent(config, CountingBus(), status_hz=0.0)


def test_status_and_liveliness_on_the_bus(config: FleetConfig, bus: StatusBus) -> None:
    seen: list[Any] = []
    joined = threading.Event()
    left = threading.Event()
    got = threading.Event()

    def on_status(rec: Any) -> None:
        seen.append(rec)
        got.set()

    bus.subscribe_statuses(on_status)
    bus.watch_alive(
        lambda robot: joined.set() if robot == "robot1" else None,
        lambda robot: left.set() if robot == "robot1" else None,
    )
    lease = acquire_coordinator_lease(bus.session, 7, "test")
    watch = LeaseWatch(bus.session)
    agent, sim = make_agent(config, bus, leases=watch.current)
    try:
        assert joined.wait(WAIT_S)
        agent.tick()
        assert got.wait(WAIT_S)
        assert seen[0].robot == "robot1" and seen[0].battery == pytest.approx(1.0)
        wait_until(lambda: watch.current() == lease.lease, "the coordinator lease")
        # an order of the live coordinator's epoch on the bus reaches the agent (applied at
        # its next tick) and is acknowledged in the status
        bus.publish_task(replace(patrol_msg(config, "p-0007"), epoch=7, seq=1))
        wait_until(lambda: agent.bb.task_id == "p-0007", "the order on the agent", act=agent.tick)
        assert (agent.tick().epoch, agent.tick().order_seq) == (7, 1)
    finally:
        agent.close()
        watch.close()
        lease.release()
    assert left.wait(WAIT_S)


def test_on_change_publishing_idle_robot_heartbeats_and_a_new_order_goes_out_at_once(
    config: FleetConfig,
) -> None:
    """``status_max_period_s=2`` with ``status_hz=10``: an idle robot that nothing changes
    publishes every 2 s only; an order that changes its mode and task is published at the next
    tick, and a driving robot publishes at every status period (its pose moves)."""
    bus = CountingBus()
    agent, sim = make_agent(config, bus, status_hz=10.0, status_max_period_s=2.0)
    try:
        run(agent, sim, 6.0)  # idle at its start pose: first record, then one every 2 s
        idle = [r.t for r in bus.statuses]
        assert len(idle) == 3 and all(
            b - a == pytest.approx(2.0, abs=0.11) for a, b in zip(idle, idle[1:], strict=False)
        )
        bus.statuses.clear()
        agent.apply(patrol_msg(config, "p-0001"))
        run(agent, sim, 3.0)
        first = bus.statuses[0]
        assert first.task_id == "p-0001" and first.t == pytest.approx(6.0, abs=0.11)
        moving = [r for r in bus.statuses if r.mode == "patrol"]
        assert len(moving) >= 25  # about every tick while driving (a turn on the spot may pause)
    finally:
        agent.close()
    with pytest.raises(ValueError, match="status_max_period_s"):
        make_agent(config, CountingBus(), status_max_period_s=-1.0)


def test_before_the_first_state_the_robot_waits_without_a_safety_stop(
    config: FleetConfig, caplog: pytest.LogCaptureFixture
) -> None:
    """A robot of a simulator in another process has no pose until the simulator's first state
    arrives: its agent reports ``waiting for state`` (idle, leaf ``WaitingForState``, a
    ``localization`` warning), not a safety stop; an order given meanwhile is driven once the
    state is there, and the watchdog never tripped (real Zenoh, a real ``SimNavServer``)."""
    from fleet.bus.nav_client import ZenohNavBackend
    from fleet.bus.nav_server import SimNavServer

    ep = free_endpoint()
    clock = SimClock()
    sim = Simulator(config.grid, config.sim, clock)
    for r in config.robots:
        sim.add_robot(r)
    caplog.set_level("INFO", logger="fleet.runtime.agent")
    with open_session(ep, "router") as router, open_session(ep, "client") as client:
        backend = ZenohNavBackend(client, "/robot1")
        agent = RobotAgent("/robot1", backend, clock, CountingBus(), battery_model=config.sim.battery)
        server: SimNavServer | None = None
        try:
            agent.deliver(patrol_msg(config, "p-0001"))
            for _ in range(3):
                rec = agent.tick()
            assert (rec.mode, rec.leaf, rec.pose) == ("idle", "WaitingForState", None)
            assert rec.diag == (("localization", 1, "waiting for the robot's first state"),)
            assert agent.watchdog.trips == 0 and agent.bb.task_id == "p-0001"
            server = SimNavServer(router, sim)

            def step() -> None:
                sim.step()
                assert server is not None
                server.publish()
                agent.tick()

            wait_until(
                lambda: agent.last_status is not None and agent.last_status.mode == "patrol",
                "patrol",
                act=step,
            )
            assert agent.watchdog.trips == 0
            assert not agent.waiting_for_state
            assert "waiting for its first state" in caplog.text
            assert "safety stop" not in caplog.text
        finally:
            agent.close()
            if server is not None:
                server.close()
            backend.close()
