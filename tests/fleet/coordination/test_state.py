"""CoordinatorState decisions for patrol fleets, without a network: assignment by roadmap
travel cost, fresh ids, reassignment on death / stuck / charging, stale statuses that must not
count, and a bounded event log."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pytest

from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.coordination import archive
from fleet.coordination.state import MAX_EVENTS, CoordinatorState, state_from_config
from fleet.coordination.tasks import PatrolRoute
from fleet.coordination.views import (
    REASON_CHARGING,
    REASON_DEAD,
    REASON_STUCK,
    CoordinatorParams,
    Observation,
    Reason,
    RobotView,
    TaskOrder,
)
from fleet.roadmap.graph import Roadmap
from fleet.types import Pose2D, TaskKind

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


@pytest.fixture(scope="module")
def config() -> FleetConfig:
    return load_config(PATROL)


def idle(x: float, y: float, t: float = 0.0, battery: float = 1.0) -> Observation:
    return Observation(t=t, pose=Pose2D(x, y), battery=battery, mode="idle")


def patrol(
    x: float, y: float, task_id: str, laps: int = 0, t: float = 0.0, mode: str = "patrol"
) -> Observation:
    return Observation(t=t, pose=Pose2D(x, y), mode=mode, task_id=task_id, laps=laps)


def patrols(orders: list[TaskOrder]) -> dict[str, TaskOrder]:
    return {o.robot: o for o in orders if o.kind == "patrol"}


def line_state(**kw: float) -> CoordinatorState:
    """A 1-D roadmap 0..100 m with two short routes at the ends."""
    rm = Roadmap.from_config_dict(
        {
            "nodes": {"a": [0, 0], "b": [5, 0], "m": [50, 0], "c": [95, 0], "d": [100, 0]},
            "edges": [["a", "b"], ["b", "m"], ["m", "c"], ["c", "d"]],
        }
    )
    routes = [
        PatrolRoute("west", rm.poses_for(["a", "b"], closed=True), ("a", "b")),
        PatrolRoute("east", rm.poses_for(["c", "d"], closed=True), ("c", "d")),
    ]
    params = CoordinatorParams(stuck_reassign_s=30.0, status_timeout_s=3.0, battery_low=0.25)
    for k, v in kw.items():
        setattr(params, k, v)
    chargers = [Pose2D(0, 1), Pose2D(100, 1)]
    return CoordinatorState(routes, chargers, rm, params)


def test_nearest_robot_gets_each_route() -> None:
    s = line_state()
    s.observe("r_east", 0.0, idle(99, 0))
    s.observe("r_west", 0.0, idle(2, 0))
    s.observe("r_mid", 0.0, idle(50, 0))
    got = patrols(s.step(0.0))
    assert got["r_west"].route == "west"
    assert got["r_east"].route == "east"
    assert "r_mid" not in got  # the spare idles
    assert s.waiting_routes == []


def test_global_matching_not_first_come() -> None:
    # r1 is listed first and is nearer the west route, r2 is right on it: greedy per robot
    # would give r1 the west route; the global matching gives it to r2.
    s = line_state()
    s.observe("r1", 0.0, idle(20, 0))
    s.observe("r2", 0.0, idle(0, 0))
    got = patrols(s.step(0.0))
    assert got["r2"].route == "west"
    assert got["r1"].route == "east"


def test_lap_starts_at_the_nearest_waypoint(config: FleetConfig) -> None:
    s = state_from_config(config)
    x, y = config.roadmap.pos("a2_n")
    s.observe("robot1", 0.0, idle(x, y + 0.3))
    o = patrols(s.step(0.0))["robot1"]
    assert o.route == "aisles_1_2"
    assert (o.poses[0].x, o.poses[0].y) == (x, y)
    assert len(o.poses) == len(config.route_poses(config.route("aisles_1_2")))


def test_ids_unique_and_increasing_and_orders_carry_chargers(config: FleetConfig) -> None:
    s = state_from_config(config)
    for r in config.robots:
        s.observe(r.name, 0.0, idle(r.start.x, r.start.y))
    orders = s.step(0.0)
    assert len(patrols(orders)) == len(config.routes)
    ids = [o.task_id for o in orders]
    assert ids == sorted(ids) and len(set(ids)) == len(ids)
    assert all(i.startswith("p-") for i in ids)
    assert all(o.charger is not None for o in orders)
    # balanced: both chargers are used
    assert {(o.charger.x, o.charger.y) for o in orders if o.charger} == {
        (c.pose.x, c.pose.y) for c in config.chargers
    }
    # a robot that dies and a new assignment: ids keep growing, never reused
    victim = orders[0].robot
    s.robot_left(victim, 1.0)
    later = s.step(1.0)
    new = [o.task_id for o in later if o.task_id not in ids]
    assert new and min(new) > max(ids)
    assert [o.robot for o in later if o.kind == "patrol" and o.task_id not in ids] != [victim]


def test_reassign_when_robot_dies_by_liveliness() -> None:
    s = line_state()
    s.observe("a", 0.0, idle(1, 0))
    s.observe("b", 0.0, idle(90, 0))
    s.observe("spare", 0.0, idle(10, 0))
    first = patrols(s.step(0.0))
    assert first["a"].route == "west"
    s.observe("a", 0.5, patrol(2, 0, first["a"].task_id))
    s.observe("b", 0.5, patrol(96, 0, first["b"].task_id))
    s.observe("spare", 0.5, idle(10, 0))
    s.step(0.5)
    s.robot_left("a", 1.0)
    got = patrols(s.step(1.0))
    assert got["spare"].route == "west"
    (r,) = s.reassignments
    assert (r.route, r.from_robot, r.reason, r.to_robot) == ("west", "a", REASON_DEAD, "spare")
    assert r.t == 1.0 and r.t_reassigned == 1.0
    assert r.new_task_id == got["spare"].task_id != r.old_task_id


def test_reassign_when_robot_goes_silent() -> None:
    s = line_state(status_timeout_s=3.0)
    s.observe("a", 0.0, idle(1, 0))
    s.observe("b", 0.0, idle(99, 0))
    tid = patrols(s.step(0.0))["a"].task_id
    s.observe("spare", 0.0, idle(10, 0))
    for t in (1.0, 2.0, 3.0):
        s.observe("a", t, patrol(1 + t, 0, tid))
        s.observe("spare", t, idle(10, 0))
        assert not patrols(s.step(t)).get("spare")
    s.observe("spare", 6.5, idle(10, 0))
    s.robots["b"].last_seen = 6.5
    got = patrols(s.step(6.5))
    assert got["spare"].route == "west"
    assert s.reassignments[0].reason == REASON_DEAD
    assert not s.robots["a"].alive


def test_reassign_when_stuck_and_cooldown() -> None:
    s = line_state(stuck_reassign_s=30.0, ack_timeout_s=1000.0)  # "b" never acknowledges its order
    s.observe("a", 0.0, idle(1, 0))
    s.observe("b", 0.0, idle(99, 0))
    tid = patrols(s.step(0.0))["a"].task_id
    t = 0.0
    while t < 29.0:
        t += 1.0
        s.observe("a", t, patrol(3, 0, tid))  # never moves
        s.observe("b", t, idle(99, 0))
        s.observe("spare", t, idle(10, 0))
        assert s.reassignments == [], t
        s.step(t)
    t = 31.5
    s.observe("a", t, patrol(3, 0, tid))
    s.observe("b", t, idle(99, 0))
    s.observe("spare", t, idle(10, 0))
    orders = s.step(t)
    got = patrols(orders)
    assert got["spare"].route == "west"
    assert s.reassignments[0].reason == REASON_STUCK
    assert any(o.robot == "a" and o.kind == "idle" for o in orders)
    # the stuck robot reports idle but is in cool-down: a farther idle robot is preferred
    s.robot_left("b", t)
    s.observe("a", t + 1, idle(3, 0))
    s.observe("spare", t + 1, patrol(10, 0, got["spare"].task_id))
    s.observe("far", t + 1, idle(60, 0))
    got2 = patrols(s.step(t + 1))
    assert "a" not in got2 and got2["far"].route == "east"
    # with nobody else free it gets a route again
    s.robot_left("far", t + 2)
    s.observe("a", t + 2, idle(3, 0))
    s.observe("spare", t + 2, patrol(10, 0, got["spare"].task_id))
    assert patrols(s.step(t + 2))["a"].route == "east"


def test_waypoint_blocked_by_a_dead_robot_is_skipped() -> None:
    rm = Roadmap.from_config_dict(
        {"nodes": {"a": [0, 0], "b": [10, 0], "c": [20, 0]}, "edges": [["a", "b"], ["b", "c"]]}
    )
    route = PatrolRoute("line", rm.poses_for(["a", "b", "c"], closed=True), ("a", "b", "c"))
    s = CoordinatorState([route], [Pose2D(0, 1)], rm, CoordinatorParams(stuck_reassign_s=10.0))
    s.observe("r1", 0.0, idle(1, 0))
    s.observe("r2", 0.0, idle(5, 0))
    o = patrols(s.step(0.0))["r1"]
    # r1 dies on waypoint c; r2 takes over and gets stuck 0.7 m before c
    s.robot_left("r1", 1.0)
    o2 = patrols(s.step(1.0))["r2"]
    assert o2.task_id != o.task_id and len(o2.poses) == 3
    for t in range(2, 14):
        s.observe("r2", float(t), patrol(19.3, 0, o2.task_id))
        s.step(float(t))
    assert s.reassignments[-1].reason == REASON_STUCK
    s.observe("r2", 14.0, idle(19.3, 0))
    o3 = patrols(s.step(14.0))["r2"]  # nobody else: r2 again, without the blocked waypoint
    assert sorted((p.x, p.y) for p in o3.poses) == [(0.0, 0.0), (10.0, 0.0)]


def test_moving_robot_is_not_stuck() -> None:
    s = line_state(stuck_reassign_s=30.0)
    s.observe("a", 0.0, idle(1, 0))
    tid = patrols(s.step(0.0))["a"].task_id
    for k in range(1, 100):
        x = 1 + (k % 8)  # back and forth, always making progress
        s.observe("a", float(k), patrol(x, 0, tid))
        s.step(float(k))
    assert s.reassignments == []


def test_charging_robot_loses_route_and_gets_one_back_when_idle() -> None:
    s = line_state()
    s.observe("a", 0.0, idle(1, 0))
    s.observe("b", 0.0, idle(99, 0))
    first = patrols(s.step(0.0))
    s.observe("spare", 1.0, idle(20, 0))
    s.observe("a", 1.0, patrol(0, 0.5, first["a"].task_id, mode="charging"))
    orders = s.step(1.0)
    got = patrols(orders)
    assert got["spare"].route == "west"
    assert s.reassignments[0].reason == REASON_CHARGING
    assert [o.kind for o in orders if o.robot == "a"] == ["idle"]
    # still charging: nothing for it; back to idle with a full battery: the route freed meanwhile
    s.observe("a", 2.0, Observation(t=2.0, pose=Pose2D(0, 0.5), mode="charging", battery=0.5))
    assert "a" not in patrols(s.step(2.0))
    s.robot_left("b", 50.0)
    s.observe("spare", 50.0, patrol(3, 0, got["spare"].task_id))
    s.observe("a", 50.0, idle(0, 0.5, battery=0.96))
    assert patrols(s.step(50.0))["a"].route == "east"


def test_low_battery_robot_is_not_assigned() -> None:
    s = line_state()
    s.observe("low", 0.0, idle(1, 0, battery=0.26))
    s.observe("ok", 0.0, idle(40, 0))
    got = patrols(s.step(0.0))
    assert "low" not in got and got["ok"].route == "west"


def test_stale_status_with_old_task_id_does_not_count() -> None:
    s = line_state()
    s.observe("a", 0.0, idle(1, 0))
    old = patrols(s.step(0.0))["a"].task_id
    s.observe("a", 1.0, patrol(1, 0, old, mode="charging"))
    s.step(1.0)  # route taken back
    s.observe("spare", 2.0, idle(3, 0))
    new = patrols(s.step(2.0))["spare"].task_id
    # a late status of robot a claiming laps with its old id: credited only to the old assignment
    s.observe("a", 3.0, patrol(1, 0, old, laps=2))
    # a status from the wrong robot carrying the new id: ignored
    s.observe("a", 3.0, patrol(1, 0, new, laps=5))
    assert s.by_id[new].laps == 0
    assert s.by_id[old].laps == 2
    # duplicates and regressions do not change the count
    s.observe("spare", 4.0, patrol(3, 0, new, laps=1))
    s.observe("spare", 4.1, patrol(3, 0, new, laps=1))
    s.observe("spare", 4.2, patrol(3, 0, new, laps=0))
    assert s.by_id[new].laps == 1
    assert s.patrols_completed() == 2 and s.laps_completed() == 3


def test_unacknowledged_order_is_resent_same_id() -> None:
    s = line_state()
    s.observe("a", 0.0, idle(1, 0))
    o = patrols(s.step(0.0))["a"]
    s.observe("a", 0.5, idle(1, 0))  # it has not got the order yet
    assert s.step(0.5) == []  # too soon to resend
    s.observe("a", 1.5, idle(1, 0))
    (again,) = s.step(1.5)
    assert again == o
    s.observe("a", 2.0, patrol(2, 0, o.task_id))
    assert s.step(3.0) == []


def test_robot_without_route_still_patrolling_is_told_to_idle() -> None:
    s = line_state()
    s.observe("ghost", 0.0, patrol(50, 0, "p-0099"))
    orders = s.step(0.0)
    assert [(o.robot, o.kind) for o in orders] == [("ghost", "idle")]


def test_1000_robots_each_get_the_nearest_route_in_one_cycle() -> None:
    # robot i stands 0.2 m from node n(1000-i), which routes r(999-i) and r(1000-i) share: the
    # global matching gives every robot a route entered at its own node (how fast: see
    # bench/bench_coordinator.py)
    n = 1000
    nodes = {f"n{i}": [float(i), 0.0] for i in range(n + 1)}
    edges = [[f"n{i}", f"n{i + 1}"] for i in range(n)]
    rm = Roadmap.from_config_dict({"nodes": nodes, "edges": edges})
    routes = [
        PatrolRoute(f"r{i}", rm.poses_for([f"n{i}", f"n{i + 1}"]), (f"n{i}", f"n{i + 1}")) for i in range(n)
    ]
    s = CoordinatorState(routes, [Pose2D(0, 0)], rm)
    for i in range(n):
        s.observe(f"robot{i}", 0.0, idle(float(n - i) - 0.2, 0.0))
    got = patrols(s.step(0.0))
    assert len(got) == n and s.waiting_routes == []
    for i in range(n):
        o = got[f"robot{i}"]
        assert o.route == f"r{n - 1 - i}"
        assert o.poses[0].x == float(n - i)  # the lap starts at the robot's node
    assert len({o.task_id for o in got.values()}) == n
    assert s.step(0.1) == []  # nothing waits, nothing to resend yet


def test_event_log_is_bounded() -> None:
    s = line_state()
    for k in range(MAX_EVENTS + 50):
        s.robot_joined(f"r{k}", float(k))
    assert len(s.events) == MAX_EVENTS
    assert s.events[-1] == (float(MAX_EVENTS + 49), f"r{MAX_EVENTS + 49} joined")


def test_an_order_never_acknowledged_is_reissued_under_a_new_id() -> None:
    s = line_state(ack_timeout_s=5.0)
    s.observe("a", 0.0, idle(1, 0))
    s.observe("b", 0.0, idle(99, 0))
    orders = patrols(s.step(0.0))
    tid_a, first = orders["a"].task_id, orders["b"]
    issued = [first.task_id]
    t = 0.0
    while t < 12.0:  # "b" never shows its order: it was lost (its agent started after it was sent)
        t += 1.0
        s.observe("a", t, patrol(1 + t, 0, tid_a))
        s.observe("b", t, idle(99, 0))
        got = patrols(s.step(t)).get("b")
        if got is not None and got.task_id not in issued:
            assert got.route == first.route
            issued.append(got.task_id)
    # re-issued every ack_timeout_s, each time under a new id (never the same id forever)
    assert len(issued) == 3 and len(set(issued)) == 3
    assert [(r.reason, r.to_robot) for r in s.reassignments] == [(Reason.NO_ACK, "b")] * 2
    # once the robot shows the id, it keeps its task
    for dt in range(1, 10):
        s.observe("a", t + dt, patrol(1 + t + dt, 0, tid_a))
        s.observe("b", t + dt, patrol(99 - dt, 0, issued[-1]))
        assert patrols(s.step(t + dt)).get("b") is None
    assert len(s.reassignments) == 2


def test_a_long_run_keeps_the_newest_assignments_and_every_total(monkeypatch: pytest.MonkeyPatch) -> None:
    """Hours of hand-overs (robots going to charge) keep only the newest assignment and
    reassignment records (:mod:`fleet.coordination.archive`); laps, completions and counts
    still cover the whole run, and a lap reported late for a recent assignment still counts."""
    monkeypatch.setattr(archive, "KEEP_RECORDS", 4)
    monkeypatch.setattr(archive, "ARCHIVE_AFTER_S", 10.0)
    st = line_state()
    book = st.book
    laps = dict.fromkeys(("r1", "r2"), 0)
    t = 0.0
    for k in range(60):
        robot = ("r1", "r2")[k % 2]
        a, _ = book.assign("west", robot, book.next_id("p"), (), t)
        if k % 3:  # two hand-overs in three drive a lap or two before going to charge
            book.record(robot, patrol(0.0, 0.0, a.task_id, laps=1 + k % 2), t + 1.0, a)
            laps[robot] += 1 + k % 2
        book.release(a, t + 2.0, "charging")
        t += 3.0
    book.record(robot, patrol(0.0, 0.0, a.task_id, laps=3), t, None)  # late news of the last one
    laps[robot] += 3 - (1 + 59 % 2)
    assert len(book.records) <= 2 * 4 + 1 and len(book.by_id) == len(book.records)
    assert len(book.reassignments) <= 2 * 4
    assert st.assigned(TaskKind.PATROL) == 60 and st.reassignment_count() == 60
    assert st.laps_completed() == sum(laps.values()) and st.laps_by_robot() == laps
    assert st.laps_by_route() == {"west": sum(laps.values()), "east": 0}
    assert st.patrols_completed() == 40


class CountingTraffic:
    """A traffic policy that only counts its cycles and the robots each one saw."""

    def __init__(self) -> None:
        self.cycles: list[set[str]] = []

    def on_assign(
        self, robot: str, route: object, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]:
        return poses

    def on_release(self, robot: str) -> None:
        pass

    def waiting(self, robot: str) -> bool:
        return False

    def cycle(self, now: float, robots: Mapping[str, RobotView]) -> tuple[()]:
        self.cycles.append({n for n, v in robots.items() if v.obs is not None})
        return ()


def test_the_first_traffic_cycle_waits_for_every_robot() -> None:
    """A restarted coordinator's traffic (its charger queue) starts only once every robot has
    reported, or ``settle_s`` passed: a charger taken by a silent robot is not handed out."""
    st = line_state()
    st.traffic = traffic = CountingTraffic()
    st.expect(["r1", "r2"], settle_s=3.0)
    st.observe("r1", 0.0, Observation(t=0.0, pose=Pose2D(50, 0), battery=0.3, mode="charging"))
    st.step(0.0)
    st.step(1.0)
    assert traffic.cycles == []
    st.observe("r2", 1.5, idle(0, 1, t=1.5, battery=0.6))  # on the west charger
    st.step(1.5)
    assert traffic.cycles == [{"r1", "r2"}]
    late = line_state()
    late.traffic = late_traffic = CountingTraffic()
    late.expect(["r1", "r2"], settle_s=3.0)
    late.observe("r1", 0.0, idle(50, 0))
    late.step(0.0)
    late.step(2.9)
    late.step(3.0)  # r2 never reported: the fleet goes on without it
    assert late_traffic.cycles == [{"r1"}]
