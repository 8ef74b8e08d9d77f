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


def test_a_batch_that_changes_a_few_ids_answers_as_a_fresh_one(tmp_path: object) -> None:
    """A poller asks for nearly the same ids each time; the batch reuses its last answer for
    the ids that did not change. Re-sent goals, ids set to ``None``, unknown and malformed ids
    and a reordered list, over 100 robots patrolling: every answer equals that of a new
    simulator-side batch reader with nothing remembered (and of the NumPy path)."""
    from fleet.clock import SimClock
    from fleet.config.loader import load_config
    from fleet.warehouse import generate_warehouse
    from sim.batch import SimBatch
    from sim.goals import TERMINAL
    from sim.simulator import Simulator

    cfg = load_config(generate_warehouse(str(tmp_path), "batch", 100), robots=100)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    for spec in cfg.robots:
        sim.add_robot(spec)
    nss = sim.namespaces
    routes = [cfg.route_poses(r) for r in cfg.routes]
    ids: list[str | None] = [
        sim.send_goal(ns, NavigateThroughPoses(routes[i % len(routes)])) for i, ns in enumerate(nss)
    ]
    rng = np.random.default_rng(3)
    fields = ("goal_status", "goal_error", "distance_remaining", "x", "battery")
    resent = 0
    for step in range(240):
        sim.step()
        if step % 4:
            continue
        for k in rng.choice(len(ids), 3, replace=False).tolist():
            ids[k] = [None, "/nobody#3", f"{nss[k]}#x", f"{nss[k]}#1", ids[k]][int(rng.integers(5))]
        if step == 100:
            ids.reverse()
            ids.reverse()
        victim = ids[int(rng.integers(len(ids)))]
        if victim is not None and step % 8 == 0:
            sim.cancel_goal(victim)  # ends CANCELED: re-sent below
        got = sim.query_batch(nss, ids)
        for compiled in (True, False):
            fresh = SimBatch(sim.state, sim.localization, sim._dispatch, sim.robot_state, compiled)
            want = fresh.query_batch(nss, list(ids))
            for name in fields:
                assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), (step, name)
        for k in TERMINAL[got.goal_status].nonzero()[0].tolist():
            ids[k] = sim.send_goal(nss[k], NavigateThroughPoses(routes[k % len(routes)]))
            resent += 1
    assert resent > 5
    assert {GOAL_CODES[s] for s in GOAL_CODES if s.value in ("executing", "canceled")} <= set(
        got.goal_status.tolist()
    ) | {GOAL_CODES[s] for s in GOAL_CODES if s.value == "canceled"}


def test_robot_state_after_a_goal_sent_is_the_row_of_the_arrays() -> None:
    """Between steps a goal sent or a robot written refreshes only that robot's row of the
    copy ``robot_state`` reads; every robot's state still equals the arrays' values."""
    sim = make_sim(ROBOTS)
    nss = list(ROBOTS)
    for _ in range(5):
        sim.step()
    before = [sim.robot_state(ns) for ns in nss]
    gid = sim.send_goal("/r2", NavigateToPose(Pose2D(10.0, 3.0, 0.0)))
    r1 = sim._dispatch.robots["/r1"]
    r1.battery = 0.25
    r1.x = r1.x + 0.5
    for ns in nss:
        rs = sim.robot_state(ns)
        i = sim._dispatch.robots[ns].index
        s = sim.state
        assert (rs.pose.x, rs.pose.y, rs.battery) == (s.x.item(i), s.y.item(i), s.battery.item(i))
    assert sim.robot_state("/r1").battery == 0.25 and sim.robot_state("/r3") == before[2]
    # the new goal's feedback reads the row refreshed with its path (the batch reads the arrays)
    rem = sim.goal_state(gid).feedback.distance_remaining_m
    assert rem is not None and rem > 8.0
    assert rem == sim.query_batch(["/r2"], [gid]).distance_remaining[0]
    sim.step()
    i = sim._dispatch.robots["/r1"].index
    assert sim.robot_state("/r1").battery == sim.state.battery.item(i) <= 0.25
