"""The simulator's batch query (``sim.batch``) against its per-goal queries, over a run with
several robots driving, waiting, finishing, canceled and mislocalized."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim_testworld import make_sim

from fleet.errors import BackendError
from fleet.navigation import GOAL_CODES, NO_GOAL, query_batch
from fleet.types import NavigateThroughPoses, NavigateToPose, Pose2D, Spin, Wait
from sim.backend import NamespacedBackend

ROBOTS = {
    "/r1": Pose2D(1.0, 1.0, 0.0),
    "/r2": Pose2D(1.0, 3.0, 0.0),
    "/r3": Pose2D(1.0, 6.5, 0.0),
    "/r4": Pose2D(3.0, 6.5, 0.0),
}


def _check_rows(sim, backends, ids):  # type: ignore[no-untyped-def]
    batch = query_batch(backends, ids)
    for k, (b, gid) in enumerate(zip(backends, ids, strict=True)):
        rs = b.robot_state()
        assert (batch.x[k], batch.y[k], batch.theta[k]) == pytest.approx(
            (rs.pose.x, rs.pose.y, rs.pose.theta)
        )
        assert batch.battery[k] == pytest.approx(rs.battery)
        assert bool(batch.localized[k]) is rs.localized
        assert bool(batch.stuck[k]) is rs.stuck and bool(batch.charging[k]) is rs.charging
        if gid is None:
            assert batch.goal_status[k] == NO_GOAL
            continue
        gs = b.goal_state(gid)
        assert batch.goal_status[k] == GOAL_CODES[gs.status], (k, gs)
        assert batch.goal_error[k] == gs.error_code
        rem = gs.feedback.distance_remaining_m
        assert (math.isnan(batch.distance_remaining[k]) and rem is None) or batch.distance_remaining[
            k
        ] == pytest.approx(rem, abs=1e-9)
    return batch


def test_batch_rows_agree_with_per_goal_queries_through_a_run() -> None:
    sim = make_sim(ROBOTS)
    backends = [sim.backend(ns) for ns in ROBOTS]
    assert all(b.batch_server is sim for b in backends)  # one vectorized call, not a loop
    ids: list[str | None] = [
        backends[0].send_goal(NavigateToPose(Pose2D(10.0, 1.5, 0.0))),
        backends[1].send_goal(NavigateThroughPoses((Pose2D(3.0, 3.0, 0.0), Pose2D(4.0, 6.0, 1.0)))),
        backends[2].send_goal(Wait(1.0)),
        None,
    ]
    seen = set()
    for step in range(200):
        if step == 30:
            ids[3] = backends[3].send_goal(Spin(math.pi))
        if step == 60:
            backends[1].cancel_goal(ids[1])  # type: ignore[arg-type]
        if step == 80:
            sim.set_initial_pose("/r4", Pose2D(8.0, 2.0, 0.0))  # far off: mislocalized
        batch = _check_rows(sim, backends, ids)
        seen.update(int(c) for c in batch.goal_status)
        sim.step()
    assert {GOAL_CODES[s] for s in GOAL_CODES if s.value in ("executing", "succeeded", "canceled")} <= seen
    assert not bool(query_batch(backends, ids).localized[3])


def test_unknown_goal_is_no_goal_and_unknown_robot_raises() -> None:
    sim = make_sim(ROBOTS)
    batch = sim.query_batch(["/r1", "/r1"], ["/r1#999", None])
    assert list(batch.goal_status) == [NO_GOAL, NO_GOAL]
    with pytest.raises(BackendError):
        sim.query_batch(["/nobody"], [None])
    with pytest.raises(ValueError):
        sim.query_batch(["/r1"], [])


def test_a_server_without_a_batch_query_answers_by_a_loop() -> None:
    sim = make_sim(ROBOTS)

    class PerGoalOnly:  # the GoalServer reads only, as a world without a batch query has them
        def send_goal(self, ns, goal):  # type: ignore[no-untyped-def]
            return sim.send_goal(ns, goal)

        def goal_state(self, gid):  # type: ignore[no-untyped-def]
            return sim.goal_state(gid)

        def cancel_goal(self, gid):  # type: ignore[no-untyped-def]
            sim.cancel_goal(gid)

        def robot_state(self, ns):  # type: ignore[no-untyped-def]
            return sim.robot_state(ns)

    server = PerGoalOnly()
    backends = [NamespacedBackend(server, ns) for ns in ROBOTS]  # type: ignore[arg-type]
    assert backends[0].batch_server is backends[3].batch_server
    gid = backends[0].send_goal(NavigateToPose(Pose2D(10.0, 1.5, 0.0)))
    for _ in range(20):
        sim.step()
    loop = query_batch(backends, [gid, None, None, None])
    fast = query_batch([sim.backend(ns) for ns in ROBOTS], [gid, None, None, None])
    for name in ("x", "y", "theta", "battery", "goal_status", "distance_remaining"):
        assert np.allclose(getattr(loop, name), getattr(fast, name), equal_nan=True), name
