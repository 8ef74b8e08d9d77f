"""The Zenoh navigation bridge against a simulator served by another process."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from bus_peer import settle, wait_until

from fleet.bus.clock import BusClock
from fleet.bus.nav_client import ZenohNavBackend
from fleet.bus.session import open_session
from fleet.navigation import NavigationBackend
from fleet.types import ErrorCode, GoalStatus, NavigateToPose, Pose2D, Wait

REACHABLE = Pose2D(8.5, 4.0, 1.5708)
SPEED = 10.0


def _wait_ready(p: subprocess.Popen[str]) -> None:
    assert p.stdout is not None
    line = p.stdout.readline()
    assert line.strip() == "ready", (line, p.stderr.read() if p.poll() is not None and p.stderr else "")


@pytest.fixture
def served(spawn, zenoh_endpoint: str) -> Iterator[tuple[subprocess.Popen[str], ZenohNavBackend, BusClock]]:
    p = spawn(["tests/helpers/bus_peer.py", "navserver", zenoh_endpoint, str(SPEED)])
    _wait_ready(p)
    session = open_session(zenoh_endpoint, "client")
    backend = ZenohNavBackend(session, "/robot1")
    clock = BusClock(session)
    try:
        assert backend.wait_for_server(30.0)
        assert clock.wait_first(30.0)
        yield p, backend, clock
    finally:
        backend.close()
        clock.close()
        session.close()


def _status_is(b: ZenohNavBackend, gid: str, *statuses: GoalStatus) -> bool:
    return b.goal_state(gid).status in statuses


def _ended(b: ZenohNavBackend, gid: str) -> bool:
    return b.goal_state(gid).status.terminal


def test_navigate_to_pose_succeeds(served) -> None:
    _, b, clock = served
    assert isinstance(b, NavigationBackend)
    gid = b.send_goal(NavigateToPose(REACHABLE))
    assert _status_is(b, gid, GoalStatus.PENDING, GoalStatus.EXECUTING)
    wait_until(lambda: _ended(b, gid), 60, "the goal to end")
    st = b.goal_state(gid)
    assert st.status is GoalStatus.SUCCEEDED, st.error_msg
    assert st.goal_id == gid
    pose = b.robot_state().pose
    assert pose is not None and pose.distance_to(REACHABLE) < 0.35
    assert clock.now() > 1.0
    assert b.malformed == 0 and clock.malformed == 0


def test_cancel_and_preemption(served) -> None:
    _, b, clock = served
    gid = b.send_goal(NavigateToPose(REACHABLE))
    wait_until(lambda: _status_is(b, gid, GoalStatus.EXECUTING), 20, "executing")
    b.cancel_goal(gid)
    b.cancel_goal(gid)  # idempotent
    wait_until(lambda: _ended(b, gid), 20, "the canceled goal to end")
    assert b.goal_state(gid).status is GoalStatus.CANCELED
    b.cancel_goal(gid)  # a finished goal: no-op
    assert b.goal_state(gid).status is GoalStatus.CANCELED
    first = b.send_goal(Wait(30.0))
    wait_until(lambda: _status_is(b, first, GoalStatus.EXECUTING), 20, "the first wait executing")
    second = b.send_goal(Wait(0.5))
    wait_until(lambda: _ended(b, first), 20, "the first wait to be preempted")
    assert b.goal_state(first).status is GoalStatus.ABORTED
    wait_until(lambda: _status_is(b, second, GoalStatus.SUCCEEDED), 20, "the second wait to succeed")
    with pytest.raises(KeyError):
        b.goal_state("/robot1@nobody#1")


def test_server_killed_mid_goal_aborts_with_server_unavailable(served) -> None:
    p, b, _ = served
    gid = b.send_goal(NavigateToPose(REACHABLE))
    wait_until(lambda: _status_is(b, gid, GoalStatus.EXECUTING), 20, "executing")
    p.kill()
    p.wait(5)
    wait_until(lambda: _ended(b, gid), 3 * b.timeout_s + 5, "the goal to end after the server died")
    st = b.goal_state(gid)
    assert st.status is GoalStatus.ABORTED
    assert st.error_code == ErrorCode.SERVER_UNAVAILABLE
    assert not b.connected
    # a goal sent with no server at all also ends, it does not hang
    late = b.send_goal(Wait(1.0))
    wait_until(lambda: _ended(b, late), 3 * b.timeout_s + 5, "a goal without a server to end")
    assert b.goal_state(late).error_code == ErrorCode.SERVER_UNAVAILABLE


def test_unencodable_goal_is_rejected_at_once(served) -> None:
    _, b, _ = served
    gid = b.send_goal(NavigateToPose(Pose2D(float("nan"), 0.0, 0.0)))
    st = b.goal_state(gid)
    assert st.status is GoalStatus.REJECTED
    assert "goal_request.goal.pose[0]: expected a finite number, got nan" in st.error_msg


def test_server_dedupes_resends_late_goals_and_early_cancels(zenoh_endpoint: str) -> None:
    """The server side in-process, driven step by step, with raw requests on the wire."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "testing"))
    from conformance_harness import SIM_PARAMS, SIM_WORLD, conformance_grid

    from fleet.bus.nav_server import SimNavServer
    from fleet.clock import SimClock
    from fleet.messages import goal_to_dict
    from fleet.robots import RobotSpec
    from sim.simulator import Simulator

    sim = Simulator(conformance_grid(), SIM_PARAMS, SimClock())
    sim.add_robot(RobotSpec("robot1", "/robot1", SIM_WORLD.start))
    with open_session(zenoh_endpoint, "router") as router, open_session(zenoh_endpoint, "client") as client:
        server = SimNavServer(router, sim)
        states: list[dict[str, Any]] = []
        sub = client.declare_subscriber(
            "fleet/robot1/nav/state", lambda s: states.append(json.loads(s.payload.to_bytes()))
        )
        try:
            # both directions live: the client hears states, the server hears requests
            settle(server.publish, lambda: bool(states), 30, "a state message")
            probes: list[str] = []

            def probe() -> None:
                probes.append(f"probe{len(probes)}")
                client.put("fleet/robot1/nav/cancel", json.dumps({"v": 1, "goal_id": probes[-1]}))

            settle(probe, lambda: server.received > 0, 30, "a cancel")
            wait_until(lambda: server.received == len(probes), 20, "every probe")  # none left in flight
            server.process()
            received = server.received

            def goal(gid: str, seq: int, g: Wait) -> None:
                msg = {"v": 1, "goal_id": gid, "client": "c", "seq": seq, "goal": goal_to_dict(g)}
                client.put("fleet/robot1/nav/goal", json.dumps(msg))

            def pump() -> dict[str, Any]:
                n = len(states)
                server.process()
                server.publish()
                wait_until(lambda: len(states) > n, 20, "a state message")
                goals: dict[str, Any] = states[-1]["goals"]
                return goals

            client.put("fleet/robot1/nav/cancel", json.dumps({"v": 1, "goal_id": "early"}))
            goal("g2", 2, Wait(5.0))
            goal("g2", 2, Wait(5.0))  # a re-send
            # the cancel (another key) must be in before the goal it cancels early
            wait_until(lambda: server.received == received + 3, 20, "the cancel and two goals")
            goal("early", 3, Wait(5.0))
            goal("g1", 1, Wait(5.0))  # a late re-send of an older goal
            client.put("fleet/robot1/nav/goal", b"garbage")
            client.put("fleet/nobody/nav/goal", json.dumps({"v": 1, "goal_id": "x"}))
            wait_until(
                lambda: server.received == received + 5 and server.malformed == 2,
                20,
                "two goals and two bad ones",
            )
            goals = pump()
            assert goals["g2"]["status"] == "executing"
            assert goals["early"]["status"] == "canceled"
            assert goals["g1"]["status"] == "aborted"
            assert server.malformed == 2
            assert server.last_malformed == "fleet/nobody/nav/goal: no robot 'nobody' in this simulator"
            sim.goal_state("/robot1#1")  # executed once: the simulator issued one id only
            with pytest.raises(KeyError):
                sim.goal_state("/robot1#2")
        finally:
            sub.undeclare()
            server.close()
