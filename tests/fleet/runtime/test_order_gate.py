"""Orders the coordinator did not send change nothing (docs/protocol.md): the order gate's
rules, then the outsider probes of issue 11 replayed on real Zenoh sessions against a real
agent (real simulator, real tree): a forged idle order on the wildcard key, a grant with a
huge seq, a NaN grant, a grant with 100,000 laps, orders from a dead or a made-up coordinator,
a simulator clock message with t = 1e9; leases (one coordinator, one agent per robot); a
dropped first order recovered.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from msgspec.structs import replace
from ports import free_endpoint

from fleet.bus.clock import BusClock
from fleet.bus.keys import CLOCK_KEY, grant_key, nav_key
from fleet.bus.lease import (
    Lease,
    LeaseWatch,
    SimLeaseWatch,
    acquire_coordinator_lease,
    claim_robots,
    live_leases,
    next_epoch,
)
from fleet.bus.nav_client import ZenohNavBackend
from fleet.bus.nav_server import SimNavServer
from fleet.bus.session import open_session, undeclare_all
from fleet.bus.status_bus import StatusBus
from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.coordination.coordinator import Coordinator
from fleet.errors import LeaseError
from fleet.messages import Grant, TaskMessage
from fleet.messages.nav import ClockMsg, NavState
from fleet.runtime.agent import RobotAgent
from fleet.runtime.order_gate import MAX_SEQ_GAP, OrderGate
from fleet.runtime.serve import simulator_from_config
from fleet.types import Pose2D, RobotState
from sim.simulator import Simulator

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"
#: Hang guard of the waits on the bus (s): far more than loopback needs on a loaded machine.
WAIT_S = 60.0


def wait_until(pred: Callable[[], bool], what: str, act: Callable[[], Any] | None = None) -> None:
    deadline = time.monotonic() + WAIT_S
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {WAIT_S} s waiting for {what}")
        if act is not None:
            act()
        threading.Event().wait(0.01)


def order(task_id: str | None, epoch: int, seq: int, kind: str = "patrol") -> TaskMessage:
    poses = (Pose2D(1.0, 1.0, 0.0), Pose2D(2.0, 1.0, 0.0)) if kind == "patrol" else ()
    return TaskMessage(task_id=task_id, kind=kind, robot="robot1", poses=poses, epoch=epoch, seq=seq)


# ----------------------------------------------------------------------------- the rules


def test_gate_applies_only_the_live_epoch_in_sequence() -> None:
    live: list[Lease | None] = [None]
    gate = OrderGate(lambda: live[0])
    assert not gate.admit("task", order("p-1", 5, 1))  # no coordinator is live
    live[0] = Lease(5, "a")
    assert not gate.admit("task", order("p-1", 4, 1))  # a dead coordinator's epoch
    assert not gate.admit("task", order("p-1", 6, 1))  # a made-up higher epoch
    assert gate.admit("task", order("p-1", 5, 1))
    assert not gate.admit("task", order("p-1", 5, 1)) and gate.duplicates == 1  # a resend
    assert gate.admit("task", order("p-2", 5, 3))  # a lost order in between is fine
    assert not gate.admit("task", order("p-0", 5, 2))  # late
    assert not gate.admit("task", order("p-9", 5, 3 + MAX_SEQ_GAP + 1))  # a forged jump
    assert gate.admit("task", order("p-4", 5, 4))  # ... the next real order still applies
    assert gate.admit("grant", Grant("robot1", 0, 0, None, (), (), seq=1, epoch=5))  # counted apart
    assert gate.rejected == {"no live coordinator": 1, "wrong epoch": 2, "stale seq": 1, "seq jump": 1}
    assert gate.rejected_total == 5 and gate.last_rejected is not None
    # a new coordinator took over: its sequences start afresh; the old lease's orders are ignored
    live[0] = Lease(9, "b")
    assert gate.admit("task", order("p-5", 9, 1))
    assert not gate.admit("task", order("p-6", 5, 5))
    # the first lease seen again (a reconnect) keeps its sequences
    live[0] = Lease(5, "a")
    assert not gate.admit("task", order("p-4", 5, 4)) and gate.admit("task", order("p-7", 5, 5))


# ----------------------------------------------------------------------------- on the bus


@pytest.fixture(scope="module")
def config() -> FleetConfig:
    return load_config(PATROL, robots=2)


class Net:
    """A router (the coordinator's session, holding the lease), the agent's client session
    and an outsider's client session, all on loopback."""

    def __init__(self) -> None:
        self.endpoint = free_endpoint()
        self.router = open_session(self.endpoint, "router")
        self.agent_s = open_session(self.endpoint, "client", connect_timeout_s=10.0)
        self.outsider = open_session(self.endpoint, "client", connect_timeout_s=10.0)
        self.coord = StatusBus(self.router)
        self.agent_bus = StatusBus(self.agent_s, robot="robot1")

    def put(self, key: str, payload: bytes | str) -> None:
        """An outsider's put, blocking rather than dropped when the link is congested."""
        self.outsider.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def router_put(self, key: str, payload: bytes | str) -> None:
        self.router.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def close(self) -> None:
        self.coord.close()
        self.agent_bus.close()
        for s in (self.outsider, self.agent_s, self.router):
            s.close()  # type: ignore[no-untyped-call]


@pytest.fixture
def net() -> Iterator[Net]:
    n = Net()
    try:
        yield n
    finally:
        n.close()


def make_agent(config: FleetConfig, net: Net, watch: LeaseWatch) -> RobotAgent:
    clock = SimClock()
    sim = Simulator(config.grid, config.sim, clock)
    for r in config.robots:
        sim.add_robot(r)
    spec = config.robot("robot1")
    return RobotAgent(
        spec.namespace, sim.backend(spec.namespace), clock, net.agent_bus, battery_model=config.sim.battery,
        traffic=True, leases=watch.current,
    )  # fmt: skip


def test_outsider_probes_change_nothing(config: FleetConfig, net: Net) -> None:
    lease = acquire_coordinator_lease(net.router, 1000, net.endpoint)
    watch = LeaseWatch(net.agent_s)
    agent = make_agent(config, net, watch)
    try:
        wait_until(lambda: watch.current() == lease.lease, "the agent to see the coordinator lease")
        real = replace(order("p-0001", 1000, 1), charger=Pose2D(0.5, 0.5, 0.0))

        def send_real() -> None:  # until the agent's subscription is up (a copy is a duplicate)
            net.coord.publish_task(real)
            agent.tick()

        wait_until(lambda: agent.bb.task_id == "p-0001", "the real order", act=send_real)
        grant = Grant("robot1", 1, 0, "n1", ("n2",), (Pose2D(2.0, 1.0, 0.0),), task_id="p-0001",
                      purpose="patrol", laps=1, seq=1, epoch=1000)  # fmt: skip

        def send_grant() -> None:
            net.coord.publish_grant(grant)
            agent.tick()

        wait_until(lambda: agent.bb.grant == grant, "the real grant", act=send_grant)
        before = (agent.bb.task_id, agent.bb.route, agent.bb.grant)
        malformed0 = net.agent_bus.malformed
        # the probes, as an outsider would put them
        forged_idle = TaskMessage(task_id="i-9999", kind="idle").to_json()
        net.put("fleet/*/task", forged_idle)  # every robot, no epoch
        net.put("fleet/robot1/task", replace(order("p-6666", 1001, 1, "idle"), robot=None).to_json())
        huge = {**grant.to_dict(), "seq": 2**62}
        net.put(grant_key("robot1"), json.dumps(huge))  # larger than the wire allows
        net.put(grant_key("robot1"), replace(grant, seq=2**53).to_json())  # a jump
        nan = json.dumps({**grant.to_dict(), "seq": 2}).replace("2.0, 1.0, 0.0", "NaN, 1.0, 0.0")
        net.put(grant_key("robot1"), nan.encode())
        net.put(grant_key("robot1"), replace(grant, laps=100000, epoch=999, seq=2).to_json())
        # the fence: a real order sent after the probes; once it is applied, every probe was seen
        net.coord.publish_task(order("p-0002", 1000, 2))
        wait_until(lambda: agent.bb.task_id == "p-0002", "the next real order", act=agent.tick)
        gate = agent.gate
        assert gate is not None
        wait_until(lambda: gate.rejected_total >= 4, "4 rejected probes")
        wait_until(lambda: net.agent_bus.malformed >= malformed0 + 2, "2 malformed probes")
        assert gate.rejected == {"wrong epoch": 3, "seq jump": 1}, gate.rejected
        assert net.agent_bus.malformed == malformed0 + 2, net.agent_bus.last_malformed
        assert before[2] == agent.bb.grant and agent.bb.grant.laps == 1  # no probe reached the grant
        rec = agent.tick()
        assert rec.task_id == "p-0002" and (rec.epoch, rec.order_seq, rec.grant_seq) == (1000, 2, 1)
        assert rec.rejected == 4 and rec.malformed == net.agent_bus.malformed
        # a forged jump cannot lock the robot out: the next real grant still applies
        net.coord.publish_grant(replace(grant, seq=2, horizon=1))
        wait_until(lambda: agent.bb.grant.seq == 2, "the next real grant", act=agent.tick)
        # the coordinator dies: its orders are no longer applied
        lease.release()
        wait_until(lambda: watch.current() is None, "the lease to go")
        net.coord.publish_task(order("p-0003", 1000, 3))
        wait_until(lambda: gate.rejected_total >= 5, "the dead epoch's order")
        assert gate.rejected["no live coordinator"] == 1, gate.rejected
        assert agent.tick().task_id == "p-0002"
    finally:
        agent.close()
        watch.close()
        lease.release()


def test_a_second_coordinator_and_a_second_agent_are_refused(net: Net) -> None:
    lease = acquire_coordinator_lease(net.router, 5, net.endpoint)
    token = net.agent_s.liveliness().declare_token("fleet/robot3/alive")
    try:
        wait_until(
            lambda: _refused(lambda: claim_robots(net.outsider, ["robot3"], net.endpoint)), "the token"
        )
        with pytest.raises(LeaseError, match=rf"another coordinator is live on {net.endpoint} \(epoch 5"):
            acquire_coordinator_lease(net.outsider, 6, net.endpoint)
        with pytest.raises(LeaseError, match=rf"robot robot3 already has a live agent on {net.endpoint}"):
            claim_robots(net.outsider, ["robot2", "robot3"], net.endpoint)
        claim_robots(net.outsider, ["robot2"], net.endpoint)  # a robot without an agent is free
        lease.release()
        token.undeclare()
        # once the holders are gone, a new coordinator (a new epoch) and agent may start
        wait_until(lambda: _takes_over(net), "the freed coordinator lease")
        wait_until(
            lambda: not _refused(lambda: claim_robots(net.outsider, ["robot3"], net.endpoint)), "robot3"
        )
    finally:
        lease.release()


def test_two_agents_started_at_once_do_not_both_drive(net: Net) -> None:
    """An agent that has passed the liveliness check but not yet declared its robot's token
    still holds a claim: a second agent started in that window is refused, naming the claim."""
    first = claim_robots(net.agent_s, ["robot5"], net.endpoint)
    try:
        assert len(first) == 1  # held while the first agent's robot comes up
        wait_until(
            lambda: _refused(lambda: claim_robots(net.outsider, ["robot5"], net.endpoint)), "the claim"
        )
        with pytest.raises(
            LeaseError, match=r"robot robot5: another agent is starting .* at the same moment"
        ):
            claim_robots(net.outsider, ["robot5"], net.endpoint)
    finally:
        undeclare_all(first)
    # the first agent gave up: the robot is free again
    wait_until(lambda: not _refused(lambda: claim_robots(net.outsider, ["robot5"], net.endpoint)), "robot5")


def _refused(claim: Callable[[], None]) -> bool:
    try:
        claim()
    except LeaseError:
        return True
    return False


def _takes_over(net: Net) -> bool:
    try:
        acquire_coordinator_lease(net.outsider, 6, net.endpoint).release()
    except LeaseError:
        return False
    return True


def test_a_dropped_first_order_is_recovered_and_the_robot_gets_work(net: Net) -> None:
    """The agent drops the coordinator's first orders (it has not seen the coordinator's lease
    yet); the coordinator sends again (a new seq; after ``ack_timeout_s`` a new id) and the
    robot gets work."""
    config = load_config(PATROL, robots=1)
    lease = acquire_coordinator_lease(net.router, 42, net.endpoint)
    clock = SimClock()
    sim = Simulator(config.grid, config.sim, clock)
    for r in config.robots:
        sim.add_robot(r)
    coordinator = Coordinator(config, net.coord, clock, epoch=lease.epoch)
    known: list[Lease | None] = [None]  # the agent does not know the coordinator yet
    spec = config.robot("robot1")
    agent = RobotAgent(
        spec.namespace, sim.backend(spec.namespace), clock, net.agent_bus, battery_model=config.sim.battery,
        leases=lambda: known[0],
    )  # fmt: skip
    assert agent.gate is not None
    gate = agent.gate

    def step() -> None:
        agent.tick()
        coordinator.cycle()
        for _ in range(round(0.1 / config.sim.step_s)):
            sim.step()

    try:
        wait_until(
            lambda: gate.rejected.get("no live coordinator", 0) >= 1, "the first order dropped", act=step
        )
        known[0] = lease.lease
        wait_until(lambda: agent.bb.task_id is not None, "work for the robot", act=step)
        tid = agent.bb.task_id
        wait_until(
            lambda: coordinator.state.by_id[tid].t_started is not None, "the acknowledgement", act=step
        )
        assert coordinator.state.robots["robot1"].assignment is coordinator.state.by_id[tid]
    finally:
        agent.close()
        lease.release()


def test_a_lone_clock_jump_is_dropped_and_a_confirmed_one_followed(net: Net) -> None:
    """The probe ``t = 1e9`` on the simulator clock made every process exit: a lone jump is
    now dropped (counted), a jump the simulator confirms with its next message is followed."""
    clock = BusClock(net.agent_s)
    try:
        put = net.router_put
        wait_until(lambda: put(CLOCK_KEY, ClockMsg(10.0).to_json()) or clock.now() == 10.0, "the clock")
        net.put(CLOCK_KEY, ClockMsg(1e9).to_json())
        wait_until(
            lambda: put(CLOCK_KEY, ClockMsg(10.5).to_json()) or clock.rejected == 1, "the jump dropped"
        )
        assert clock.now() < 1000.0
        put(CLOCK_KEY, ClockMsg(5000.0).to_json())  # the simulator really jumped
        put(CLOCK_KEY, ClockMsg(5000.1).to_json())
        wait_until(lambda: clock.now() == 5000.1, "the confirmed jump")
        put(CLOCK_KEY, ClockMsg(0.0).to_json())  # a restarted simulator starts again:
        wait_until(lambda: clock.rewinds == 1, "the restarted clock")  # fleet time holds
        assert clock.now() == 5000.1
        put(CLOCK_KEY, ClockMsg(5000.2).to_json())  # until the simulator's time passes it
        wait_until(lambda: clock.now() == 5000.2, "the caught-up clock")
        assert clock.rejected == 1 and clock.malformed == 0
    finally:
        clock.close()


def test_forged_simulator_states_and_clock_are_ignored(config: FleetConfig, net: Net) -> None:
    """A fake ``nav/state`` with battery 0.05 sent a robot at 58 % to charge: states and clock
    messages are used only from a live simulator (its lease token names its session id)."""
    server = SimNavServer(net.router, simulator_from_config(load_config(PATROL, robots=1)))
    sims = SimLeaseWatch(net.agent_s)
    client = ZenohNavBackend(net.agent_s, "/robot1", sources=sims.admits)
    clock = BusClock(net.agent_s, sources=sims.admits)
    try:
        wait_until(lambda: server.publish() or client.states_received > 0, "the simulator's states")
        wait_until(lambda: server.publish() or clock.updates > 0, "the simulator's clock")
        real = client.robot_state()
        t = clock.now()
        fake = RobotState(Pose2D(1.0, 1.0, 0.0), 0.05)
        for src in ("", "0123456789abcdef", str(net.outsider.zid())):
            net.put(nav_key("/robot1", "state"), NavState.build("robot1", t, fake, {}, src).to_json())
            net.put(CLOCK_KEY, ClockMsg(1e9, src=src).to_json())
        wait_until(lambda: client.rejected >= 3 and clock.rejected >= 3, "the forged states and clock")
        assert client.robot_state() == real and client.robot_state().battery > 0.5 and clock.now() == t
        assert (client.rejected, clock.rejected, client.malformed, clock.malformed) == (3, 3, 0, 0)
    finally:
        clock.close()
        client.close()
        sims.close()
        server.close()


def test_each_coordinator_taking_over_starts_a_higher_epoch_kept_in_its_book(
    tmp_path: Path, net: Net
) -> None:
    from fleet.runtime.service_host import ServiceHost

    assert next_epoch(5, now_s=0.0) == 6 and next_epoch(0, now_s=1000.0) == 1_000_000
    config = load_config(PATROL, robots=1)
    epochs = []
    for _ in range(3):  # a coordinator, restarted twice on the same durable task book
        host = ServiceHost(config, SimClock(), tmp_path / "book", None)
        try:
            lease = host.take_lease(net.router, net.endpoint)
            epochs.append(lease.epoch)
            lease.release()
            store = host.service.store
            assert store is not None and store.counter("epoch") == lease.epoch
        finally:
            host.close()
        wait_until(lambda: not live_leases(net.outsider), "the lease to go")
    assert epochs == sorted(epochs) and len(set(epochs)) == 3
