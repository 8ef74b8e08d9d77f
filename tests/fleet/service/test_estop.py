"""Pause, resume and the e-stop latch on a live fleet: every robot stops within one simulator
step of the command, nothing moves while latched whatever an agent or the simulator is sent,
release leaves the fleet paused, and the report records who did what when."""

from __future__ import annotations

import threading
from collections.abc import Callable

from conftest import LiveFleet, wait_for

from fleet.types import GoalStatus, NavigateToPose, Pose2D


class StepLog:
    """Wraps the world's step: per step, whether the latch was applied (robots stalled) and
    every robot's position before and after."""

    def __init__(self, fleet: LiveFleet) -> None:
        self.runner = fleet.runner
        world = self.runner.world
        assert world is not None and self.runner._world_latch is not None
        self.sim = world.sim  # type: ignore[attr-defined]
        self.wl = self.runner._world_latch
        self.steps: list[tuple[bool, list[tuple[float, float]], list[tuple[float, float]]]] = []
        self.lock = threading.Lock()
        inner = world.advance

        def advance() -> None:
            stalled = bool(self.wl._stalled)
            before = self.poses()
            inner()
            with self.lock:
                self.steps.append((stalled, before, self.poses()))

        world.advance = advance  # type: ignore[method-assign]

    def poses(self) -> list[tuple[float, float]]:
        out = []
        for ns in self.sim.namespaces:
            p = self.sim.robot_state(ns).pose
            out.append((p.x, p.y))
        return out

    def count(self) -> int:
        with self.lock:
            return len(self.steps)

    def moved(self, i: int) -> bool:
        _, before, after = self.steps[i]
        return any(abs(a[0] - b[0]) + abs(a[1] - b[1]) > 1e-9 for a, b in zip(before, after, strict=True))


def test_estop_stops_every_robot_within_one_step_and_holds(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=True, robots=4)
    for a, b in (("a1_s", "a1_n"), ("a3_s", "a3_n"), ("a5_s", "a5_n"), ("a7_s", "a7_n")):
        fleet.submit({"kind": "patrol", "waypoints": [a, b], "priority": 10})
    log = StepLog(fleet)
    wait_for(
        lambda: log.count() > 5 and all(log.moved(i) for i in range(log.count() - 3, log.count())), "motion"
    )
    r = fleet.http.post("/api/fleet/estop", json={"by": "safety officer", "reason": "person in aisle"})
    returned_at = log.count()
    assert r.status_code == 200 and r.json()["state"] == "estop"
    wait_for(lambda: log.count() > returned_at + 50, "steps while latched")
    first = next(i for i, s in enumerate(log.steps) if s[0])
    assert first <= returned_at + 1, (first, returned_at)
    assert not any(log.moved(i) for i in range(first, log.count()))

    # nothing moves whatever an agent or the simulator is sent while latched
    agent = fleet.runner.agents[0]
    gid = agent.backend.send_goal(NavigateToPose(Pose2D(6.0, 18.0, 0.0)))
    assert agent.backend.goal_state(gid).status is GoalStatus.REJECTED
    for ns in log.sim.namespaces:
        log.sim.send_goal(ns, NavigateToPose(Pose2D(20.0, 5.0, 0.0)))
    assert fleet.http.post("/api/fleet/resume").status_code == 409
    fleet.submit({"kind": "go_to", "target": "a2_n"})
    n = log.count()
    wait_for(lambda: log.count() > n + 100, "steps while latched")
    assert not any(log.moved(i) for i in range(first, log.count()))

    # release: still paused, nothing moves; resume: they drive again
    assert (
        fleet.http.post("/api/fleet/release", headers={"X-Fleet-User": "carol"}).json()["state"] == "paused"
    )
    n = log.count()
    wait_for(lambda: log.count() > n + 50, "steps after release")
    assert not any(log.moved(i) for i in range(n + 1, log.count()))
    assert fleet.http.post("/api/fleet/resume").json()["state"] == "running"
    n = log.count()
    wait_for(lambda: log.count() > n + 5 and log.moved(log.count() - 1), "motion after resume")

    report = fleet.stop()
    ev = [(c["action"], c["by"]) for c in report.control_events]
    assert ("estop", "safety officer") in ev and ("release", "carol") in ev
    assert all(c["at"] for c in report.control_events)


def test_pause_keeps_tasks_and_resume_carries_on(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=True, robots=4)
    t = fleet.submit({"kind": "patrol", "waypoints": ["a2_s", "a2_n"], "laps": 2, "priority": 10})
    held = fleet.wait_state(t["id"], "active")
    log = StepLog(fleet)
    assert fleet.http.post("/api/fleet/pause").json()["state"] == "paused"
    # robots come to a stop (their goals are canceled) and then stand still
    wait_for(
        lambda: log.count() > 20 and not any(log.moved(i) for i in range(log.count() - 20, log.count())),
        "stop",
    )
    paused = fleet.task(t["id"])
    assert paused["state"] in ("assigned", "active") and paused["robot"] == held["robot"]
    fleet.http.post("/api/fleet/resume")
    resumed = fleet.task(t["id"])
    assert (
        resumed["robot"] == held["robot"] and resumed["attempts"] == held["attempts"]
    )  # kept over the pause
    assert not any(e["event"] == "requeued" for e in resumed["events"])
    done = fleet.wait_state(t["id"], "completed")
    assert done["laps"] >= 2  # (it may change hands later for a legitimate reason, e.g. charging)
