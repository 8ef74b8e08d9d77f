"""The Zenoh navigation bridge against a simulator served by another process."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

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


def _until(pred: Callable[[], bool], timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


@pytest.fixture
def served(spawn, zenoh_endpoint: str) -> Iterator[tuple[subprocess.Popen[str], ZenohNavBackend, BusClock]]:
    p = spawn(["tests/helpers/bus_peer.py", "navserver", zenoh_endpoint, str(SPEED)])
    _wait_ready(p)
    session = open_session(zenoh_endpoint, "client")
    backend = ZenohNavBackend(session, "/robot1", timeout_s=1.0)
    clock = BusClock(session)
    try:
        assert backend.wait_for_server(5.0)
        assert clock.wait_first(5.0)
        yield p, backend, clock
    finally:
        backend.close()
        clock.close()
        session.close()


def test_navigate_to_pose_succeeds(served) -> None:
    _, b, clock = served
    assert isinstance(b, NavigationBackend)
    gid = b.send_goal(NavigateToPose(REACHABLE))
    assert b.goal_state(gid).status in (GoalStatus.PENDING, GoalStatus.EXECUTING)
    assert _until(lambda: b.goal_state(gid).status.terminal, 15.0)
    st = b.goal_state(gid)
    assert st.status is GoalStatus.SUCCEEDED, st.error_msg
    assert st.goal_id == gid
    pose = b.robot_state().pose
    assert pose is not None and pose.distance_to(REACHABLE) < 0.35
    assert clock.now() > 1.0


def test_cancel_and_preemption(served) -> None:
    _, b, clock = served
    gid = b.send_goal(NavigateToPose(REACHABLE))
    assert _until(lambda: b.goal_state(gid).status is GoalStatus.EXECUTING, 3.0)
    b.cancel_goal(gid)
    b.cancel_goal(gid)  # idempotent
    assert _until(lambda: b.goal_state(gid).status.terminal, 3.0)
    assert b.goal_state(gid).status is GoalStatus.CANCELED
    b.cancel_goal(gid)  # a finished goal: no-op
    assert b.goal_state(gid).status is GoalStatus.CANCELED
    first = b.send_goal(Wait(30.0))
    assert _until(lambda: b.goal_state(first).status is GoalStatus.EXECUTING, 3.0)
    second = b.send_goal(Wait(0.5))
    assert _until(lambda: b.goal_state(first).status.terminal, 3.0)
    assert b.goal_state(first).status is GoalStatus.ABORTED
    assert _until(lambda: b.goal_state(second).status is GoalStatus.SUCCEEDED, 3.0)
    with pytest.raises(KeyError):
        b.goal_state("/robot1@nobody#1")


def test_server_killed_mid_goal_aborts_with_server_unavailable(served) -> None:
    p, b, _ = served
    gid = b.send_goal(NavigateToPose(REACHABLE))
    assert _until(lambda: b.goal_state(gid).status is GoalStatus.EXECUTING, 3.0)
    p.kill()
    p.wait(5)
    t0 = time.monotonic()
    assert _until(lambda: b.goal_state(gid).status.terminal, 3.0)
    elapsed = time.monotonic() - t0
    st = b.goal_state(gid)
    assert st.status is GoalStatus.ABORTED
    assert st.error_code == ErrorCode.SERVER_UNAVAILABLE
    assert elapsed < b.timeout_s + 0.5
    # a goal sent with no server at all also ends, it does not hang
    late = b.send_goal(Wait(1.0))
    assert _until(lambda: b.goal_state(late).status.terminal, 3.0)
    assert b.goal_state(late).error_code == ErrorCode.SERVER_UNAVAILABLE


def test_unencodable_goal_is_rejected_at_once(served) -> None:
    _, b, _ = served
    gid = b.send_goal(NavigateToPose(Pose2D(float("nan"), 0.0, 0.0)))
    assert b.goal_state(gid).status is GoalStatus.REJECTED


def test_server_dedupes_resends_late_goals_and_early_cancels(zenoh_endpoint: str) -> None:
    """The server side in-process, driven step by step, with raw requests on the wire."""
    import json
    import sys
    from pathlib import Path

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
            time.sleep(0.2)

            def goal(gid: str, seq: int, g: Wait) -> None:
                msg = {"v": 1, "goal_id": gid, "client": "c", "seq": seq, "goal": goal_to_dict(g)}
                client.put("fleet/robot1/nav/goal", json.dumps(msg))

            def pump() -> dict[str, Any]:
                n = len(states)
                server.process()
                server.publish()
                assert _until(lambda: len(states) > n, 2)
                return states[-1]["goals"]

            client.put("fleet/robot1/nav/cancel", json.dumps({"v": 1, "goal_id": "early"}))
            goal("g2", 2, Wait(5.0))
            goal("g2", 2, Wait(5.0))  # a re-send
            time.sleep(0.1)
            goal("early", 3, Wait(5.0))
            goal("g1", 1, Wait(5.0))  # a late re-send of an older goal
            client.put("fleet/robot1/nav/goal", b"garbage")
            client.put("fleet/nobody/nav/goal", json.dumps({"v": 1, "goal_id": "x"}))
            time.sleep(0.2)
            goals = pump()
            assert goals["g2"]["status"] == "executing"
            assert goals["early"]["status"] == "canceled"
            assert goals["g1"]["status"] == "aborted"
            assert server.malformed == 2
            sim.goal_state("/robot1#1")  # executed once: the simulator issued one id only
            with pytest.raises(KeyError):
                sim.goal_state("/robot1#2")
        finally:
            sub.undeclare()
            server.close()
