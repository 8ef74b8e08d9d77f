"""The bus-facing Coordinator on an in-memory bus: statuses in, orders out (published, and
handed to in-process agents at once), liveliness, and traffic grants resent while Zenoh keeps
nothing. No network, no sleeps: the fake bus calls back synchronously."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import pytest

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.coordination.coordinator import Coordinator
from fleet.coordination.state import RESEND_S
from fleet.coordination.tasks import PatrolRoute
from fleet.coordination.views import RobotView, TaskOrder
from fleet.messages import Grant, StatusRecord, TaskMessage
from fleet.types import Pose2D, TaskKind

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


class FakeBus:
    """A :class:`CoordinatorBus` that keeps what is published and lets the test play the robots."""

    def __init__(self) -> None:
        self.on_status: list[Callable[[StatusRecord], None]] = []
        self.on_join: list[Callable[[str], None]] = []
        self.on_leave: list[Callable[[str], None]] = []
        self.tasks: list[TaskMessage] = []
        self.grants: list[Grant] = []

    def subscribe_statuses(self, callback: Callable[[StatusRecord], None], /) -> object:
        self.on_status.append(callback)
        return None

    def watch_alive(self, on_join: Callable[[str], None], on_leave: Callable[[str], None], /) -> object:
        self.on_join.append(on_join)
        self.on_leave.append(on_leave)
        return None

    def publish_task(self, msg: TaskMessage, /) -> None:
        self.tasks.append(msg)

    def publish_grant(self, grant: Grant, /) -> None:
        self.grants.append(grant)

    def status(self, rec: StatusRecord) -> None:
        for cb in self.on_status:
            cb(rec)

    def leave(self, robot: str) -> None:
        for cb in self.on_leave:
            cb(robot)


class GrantingPolicy:
    """A traffic policy that grants every robot it sees once, through ``deliver``."""

    def __init__(self) -> None:
        self.deliver: Callable[[str, Grant], None] | None = None
        self.granted: set[str] = set()

    def on_assign(
        self, robot: str, route: PatrolRoute, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]:
        return poses

    def on_release(self, robot: str) -> None:
        return None

    def waiting(self, robot: str) -> bool:
        return False

    def cycle(self, now: float, robots: Mapping[str, RobotView]) -> Sequence[TaskOrder]:
        for name in robots:
            if name not in self.granted and self.deliver is not None:
                self.granted.add(name)
                self.deliver(name, Grant(robot=name, path_id=1, horizon=0, current=None, nodes=(), poses=()))
        return ()


@pytest.fixture(scope="module")
def config() -> FleetConfig:
    return load_config(PATROL)


def status(
    config: FleetConfig, robot: str, t: float, mode: str = "idle", task_id: str | None = None
) -> StatusRecord:
    start = config.robot(robot).start
    return StatusRecord(
        robot=robot, ns=f"/{robot}", t=t, pose=(start.x, start.y, start.theta), battery=1.0, charging=False,
        stuck=False, bt="RUNNING", leaf="", mode=mode, task_id=task_id, laps=0, progress=0.0,
        distance_m=0.0, collisions=0, seq=int(t * 10),
    )  # fmt: skip


def test_statuses_from_the_bus_get_orders_published(config: FleetConfig) -> None:
    bus, clock = FakeBus(), SimClock()
    c = Coordinator(config, bus, clock)
    for r in config.robots:
        bus.status(status(config, r.name, 0.0))
    orders = c.cycle()
    patrols = [o for o in orders if o.kind == TaskKind.PATROL]
    assert len(patrols) == len(config.routes)
    assert [m.task_id for m in bus.tasks] == [o.task_id for o in orders]
    assert all(m.robot == o.robot and m.kind == o.kind for m, o in zip(bus.tasks, orders, strict=True))
    # a robot's token drops: its route goes to a spare in the next cycle (once the start-up
    # settle time, status_timeout_s, is over: until then a missing robot may still be starting)
    victim = patrols[0]
    clock.set(config.coordinator.status_timeout_s)
    for r in config.robots:
        bus.status(status(config, r.name, clock.now()))
    bus.leave(victim.robot)
    again = c.cycle()
    (r,) = c.state.reassignments
    assert (r.route, r.from_robot, r.reason) == (victim.route, victim.robot, "dead")
    assert any(o.kind == TaskKind.PATROL and o.route == victim.route for o in again)
    assert not c.state.robots[victim.robot].alive


def test_local_robots_skip_the_bus(config: FleetConfig) -> None:
    bus, clock = FakeBus(), SimClock()
    name = config.robots[0].name
    c = Coordinator(config, bus, clock, local_robots={name})
    got: list[TaskMessage] = []
    c.local_deliver = {name: got.append}
    bus.status(status(config, name, 0.0))  # the bus copy of a local robot's status is ignored
    bus.leave(name)  # and so is its liveliness
    assert c.cycle() == [] and c.state.robots == {}
    c.feed_local(status(config, name, 0.0))
    assert c.cycle() == []  # the other robots of the config may still be starting
    clock.set(config.coordinator.status_timeout_s)
    c.feed_local(status(config, name, clock.now()))
    (o,) = c.cycle()
    assert got == [bus.tasks[-1]] and got[0].task_id == o.task_id and got[0].robot == name
    assert c.state.robots[name].alive


def test_feed_rejects_unknown_inputs(config: FleetConfig) -> None:
    c = Coordinator(config, None, SimClock())
    with pytest.raises(ValueError, match="kind 'status' with a str"):
        c.feed("status", "robot1")
    with pytest.raises(ValueError, match="kind 'hello'"):
        c.feed("hello", "robot1")
    c.feed("join", "robot1")
    c.cycle()
    assert c.state.robots["robot1"].alive


def test_grants_go_to_local_agents_at_once_and_are_resent_to_remote_robots(config: FleetConfig) -> None:
    bus, clock = FakeBus(), SimClock()
    local, remote = config.robots[0].name, config.robots[1].name
    policy = GrantingPolicy()
    c = Coordinator(config, bus, clock, traffic=policy, local_robots={local})
    assert policy.deliver is not None  # the coordinator delivers the policy's grants
    mine: list[Grant] = []
    c.local_grant_deliver = {local: mine.append}
    c.cycle()
    t0 = config.coordinator.status_timeout_s  # the other robots never report: traffic starts then
    clock.set(t0)
    c.feed_local(status(config, local, t0))
    bus.status(status(config, remote, t0))
    c.cycle()
    assert [g.robot for g in mine] == [local]
    assert [g.robot for g in bus.grants] == [remote]  # published once for the remote robot
    clock.set(t0 + RESEND_S / 2)
    c.cycle()
    assert len(bus.grants) == 1
    clock.set(t0 + RESEND_S)
    c.cycle()
    assert [g.robot for g in bus.grants] == [remote, remote]  # Zenoh keeps nothing: sent again
    assert len(mine) == 1
