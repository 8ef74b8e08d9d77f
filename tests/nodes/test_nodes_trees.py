"""Whole robot trees on the real simulator: patrol laps, battery preemption and return,
task switches, picking, two robots side by side, no wall-clock reads."""

from __future__ import annotations

import time

import py_trees
import pytest
from nodes_world import (
    CHARGER,
    RING_PLUG,
    RING_ROUTE,
    ROUTE_A,
    ROUTE_B,
    Loop,
    make_ring_world,
    make_world,
    pose_of,
)
from py_trees.common import Status

from fleet.clock import SimClock
from fleet.config.model import PickTask
from fleet.errors import FleetError
from fleet.robots import BatteryModel
from fleet.types import GoalStatus, NavigateThroughPoses, NavigateToPose, Pose2D, TreeKind
from nodes.blackboard import robot_blackboard
from nodes.trees import FollowRoute, build_tree, dump_tree, next_route_index, patrol_tree, picking_tree

NS = "/robot1"
BATTERY = BatteryModel()


def find(root: py_trees.behaviour.Behaviour, name: str) -> py_trees.behaviour.Behaviour:
    for node in root.iterate():
        if node.name == name:
            return node
    raise KeyError(name)


def assign_route(ns: str, task_id: str, route: tuple[Pose2D, ...]) -> None:
    bb = robot_blackboard(ns, name="agent")
    bb.route = route
    bb.task_id = task_id
    bb.charger = CHARGER


def test_next_route_index() -> None:
    assert next_route_index(ROUTE_A, None) == 0
    assert next_route_index(ROUTE_A, Pose2D(2.0, 2.0)) == 1  # standing on pose 0
    assert next_route_index(ROUTE_A, Pose2D(2.6, 2.0)) == 1  # past pose 0 towards pose 1
    assert next_route_index(ROUTE_A, Pose2D(1.0, 1.5)) == 0  # before pose 0


def test_patrol_tree_completes_laps() -> None:
    sim = make_world({NS: Pose2D(2.0, 2.0, 0.0)})
    root = patrol_tree(NS, sim.backend(NS), sim.clock, BATTERY)
    bb = robot_blackboard(NS, name="agent")
    loop = Loop(sim, root)
    loop.run(1.0)
    assert bb.mode == "idle" and bb.active_leaf == "Idle" and root.status == Status.RUNNING
    assign_route(NS, "p-1", ROUTE_A)
    progress: list[float] = []
    loop.on_tick.append(lambda: progress.append(bb.route_progress))
    assert loop.run(120.0, until=lambda: bb.laps >= 2)
    assert bb.lap_task_id == "p-1" and bb.mode == "patrol" and bb.active_leaf == "FollowRoute"
    assert all(0.0 <= p <= 1.0 for p in progress) and max(progress) == 1.0
    assert any(0.2 < p < 0.8 for p in progress)
    lap_time = sim.clock.now() / 2
    assert 8.0 < lap_time < 40.0  # a 10 m lap at <= 1 m/s
    follow = find(root, "FollowRoute")
    assert isinstance(follow, FollowRoute) and follow.cancels == 0


def test_battery_guard_preempts_patrol_charges_and_resumes(fast_battery) -> None:  # type: ignore[no-untyped-def]
    sim = make_world({NS: (Pose2D(2.0, 2.0, 0.0), 0.45)}, battery=fast_battery)
    b = sim.backend(NS)
    root = patrol_tree(NS, b, sim.clock, fast_battery)
    assign_route(NS, "p-1", ROUTE_A)
    bb = robot_blackboard(NS, name="agent")
    follow = find(root, "FollowRoute")
    assert isinstance(follow, FollowRoute)
    loop = Loop(sim, root)
    assert loop.run(5.0, until=lambda: follow.status == Status.RUNNING)
    assert loop.run(60.0, until=lambda: bb.mode == "charging")
    preempted = follow.goal_id
    assert preempted is not None
    assert b.goal_state(preempted).status is GoalStatus.CANCELED
    assert follow.status == Status.INVALID and follow.cancels == 1
    here = pose_of(sim, NS)
    far = abs(here.x - CHARGER.x) + abs(here.y - CHARGER.y)
    assert sim.robot_state(NS).battery < fast_battery.charge_threshold(far)
    charge = find(root, "Charge")
    assert loop.run(60.0, until=lambda: charge.status == Status.RUNNING and sim.robot_state(NS).charging)
    assert pose_of(sim, NS).distance_to(CHARGER) <= sim.params.charger_radius
    assert loop.run(30.0, until=lambda: bb.mode == "patrol")
    assert sim.robot_state(NS).battery >= fast_battery.resume
    assert follow.status == Status.RUNNING and follow.goal_id != preempted
    assert b.goal_state(follow.goal_id).status is GoalStatus.EXECUTING
    assert loop.run(60.0, until=lambda: bb.laps >= 1)
    assert bb.lap_task_id == "p-1"


def test_task_change_switches_routes_and_restarts_laps() -> None:
    sim = make_world({NS: Pose2D(2.0, 2.0, 0.0)})
    b = sim.backend(NS)
    root = patrol_tree(NS, b, sim.clock, BATTERY)
    bb = robot_blackboard(NS, name="agent")
    assign_route(NS, "p-1", ROUTE_A)
    loop = Loop(sim, root)
    follow = find(root, "FollowRoute")
    assert isinstance(follow, FollowRoute)
    assert loop.run(
        120.0,
        until=lambda: bb.laps >= 1 and 0.3 < bb.route_progress < 0.9 and follow.status == Status.RUNNING,
    )
    old = follow.goal_id
    assert old is not None
    assign_route(NS, "p-2", ROUTE_B)
    loop.tick()
    assert b.goal_state(old).status is GoalStatus.CANCELED
    assert follow.goal_id != old and follow.goal is not None
    lap_poses: list[Pose2D] = []
    for g in follow.legs:
        assert isinstance(g, (NavigateThroughPoses, NavigateToPose))
        lap_poses.extend(g.poses if isinstance(g, NavigateThroughPoses) else (g.pose,))
    assert sorted(lap_poses, key=Pose2D.as_tuple) == sorted(ROUTE_B, key=Pose2D.as_tuple)
    assert (bb.laps, bb.lap_task_id) == (0, "p-2")
    assert loop.run(120.0, until=lambda: bb.laps >= 1)
    assert bb.lap_task_id == "p-2"
    # the route is withdrawn: the running goal is canceled and the robot idles
    running = follow.goal_id
    bb.route = None
    bb.task_id = None
    loop.tick()
    assert bb.mode == "idle"
    assert running is not None and b.goal_state(running).status in (GoalStatus.CANCELED, GoalStatus.SUCCEEDED)


def test_patrol_recovers_from_a_blocked_aisle() -> None:
    sim = make_ring_world(NS, Pose2D(0.6, 0.6, 0.0), stuck_time_s=2.0)
    root = patrol_tree(NS, sim.backend(NS), sim.clock, BATTERY)
    assign_route(NS, "p-1", RING_ROUTE)
    bb = robot_blackboard(NS, name="agent")
    obstacle = sim.add_obstacle(*RING_PLUG)
    loop = Loop(sim, root)
    modes: list[str] = []
    loop.on_tick.append(lambda: modes.append(bb.mode))
    assert loop.run(60.0, until=lambda: bb.mode == "recovery")
    sim.remove_obstacle(obstacle)
    assert loop.run(120.0, until=lambda: bb.laps >= 1)
    recovery = find(root, "FollowRouteRecovery")
    assert recovery.recoveries_started >= 1  # type: ignore[attr-defined]
    assert "recovery" in modes and modes[-1] == "patrol"


def test_picking_tree_completes_a_pick() -> None:
    sim = make_world({NS: Pose2D(2.0, 2.0, 0.0)})
    root = picking_tree(NS, sim.backend(NS), sim.clock, BATTERY)
    bb = robot_blackboard(NS, name="agent")
    loop = Loop(sim, root)
    loop.run(0.5)
    assert bb.mode == "idle"
    shelf, drop = Pose2D(5.0, 4.0, 1.57), Pose2D(2.0, 4.5, 3.14)
    bb.charger = CHARGER
    bb.pick = PickTask("k-1", shelf=shelf, drop=drop, dwell_s=2.0)
    bb.task_id = "k-1"
    seen: list[str] = []
    loop.on_tick.append(lambda: seen.append(bb.active_leaf))
    assert loop.run(120.0, until=lambda: bb.picks_done == 1)
    assert bb.pick is None
    assert [n for i, n in enumerate(seen) if i == 0 or seen[i - 1] != n][:4] == [
        "GoToShelf",
        "Dwell",
        "GoToDrop",
        "CompletePick",
    ]
    assert pose_of(sim, NS).distance_to(drop) <= sim.params.goal_tolerance + 0.01
    loop.run(1.0)
    assert bb.mode == "idle" and bb.picks_done == 1


def test_two_robots_have_independent_blackboards() -> None:
    sim = make_world({"/robot1": Pose2D(2.0, 2.0, 0.0), "/robot2": Pose2D(6.0, 1.5, 0.0)})
    roots = [patrol_tree(ns, sim.backend(ns), sim.clock, BATTERY) for ns in ("/robot1", "/robot2")]
    assign_route("/robot1", "p-1", ROUTE_A)
    bb1, bb2 = robot_blackboard("/robot1", name="a1"), robot_blackboard("/robot2", name="a2")
    loop = Loop(sim, *roots)
    loop.run(3.0)
    assert (bb1.mode, bb2.mode) == ("patrol", "idle")
    assert bb2.route is None and bb2.task_id is None
    assign_route("/robot2", "p-2", ROUTE_B)
    assert loop.run(120.0, until=lambda: bb1.laps >= 1 and bb2.laps >= 1)
    assert (bb1.lap_task_id, bb2.lap_task_id) == ("p-1", "p-2")
    follows = [find(root, "FollowRoute") for root in roots]
    assert [f.goal_id.split("#")[0] for f in follows] == ["/robot1", "/robot2"]  # type: ignore[attr-defined]
    assert py_trees.blackboard.Blackboard.get("/robot1/route") == ROUTE_A
    assert py_trees.blackboard.Blackboard.get("/robot2/route") == ROUTE_B


def test_build_tree_and_dump() -> None:
    sim = make_world({NS: Pose2D(2.0, 2.0)})
    b = sim.backend(NS)
    patrol = build_tree(TreeKind.PATROL, NS, b, sim.clock, BATTERY)
    picking = build_tree("picking", NS, b, sim.clock, BATTERY)  # a kind as the user wrote it
    text = dump_tree(patrol)
    for name in (
        "BatteryGuard",
        "BatteryLow",
        "GoToCharger",
        "Charge",
        "FollowRoute",
        "RecoverySpin",
        "Idle",
    ):
        assert name in text
    assert "GoToShelf" in dump_tree(picking, unicode=True)
    with pytest.raises(FleetError, match="unknown behavior tree kind 'dance'; known kinds: patrol, picking"):
        build_tree("dance", NS, b, sim.clock, BATTERY)
    with pytest.raises(FleetError, match="traffic management drives patrol trees only"):
        build_tree(TreeKind.PICKING, NS, b, sim.clock, BATTERY, traffic=True)


def test_trees_never_read_the_wall_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    sim = make_world({NS: (Pose2D(2.0, 2.0, 0.0), 0.45)}, battery=BatteryModel(drain_per_m=0.05, low=0.3))
    root = patrol_tree(NS, sim.backend(NS), SimClock(), sim.params.battery)
    assign_route(NS, "p-1", ROUTE_A)
    loop = Loop(sim, root)

    def forbidden() -> float:
        raise AssertionError("the wall clock was read")

    real_tick = loop.tick

    def guarded_tick() -> None:
        with monkeypatch.context() as m:
            for fn in ("time", "monotonic", "perf_counter", "time_ns", "monotonic_ns"):
                m.setattr(time, fn, forbidden)
            real_tick()

    loop.tick = guarded_tick  # type: ignore[method-assign]
    assert loop.run(60.0, until=lambda: robot_blackboard(NS, name="x").mode == "charging")


def test_a_new_pick_replaces_the_running_one() -> None:
    sim = make_world({NS: Pose2D(2.0, 2.0, 0.0)})
    b = sim.backend(NS)
    root = picking_tree(NS, b, sim.clock, BATTERY)
    bb = robot_blackboard(NS, name="agent")
    bb.pick = PickTask("k-1", shelf=Pose2D(6.0, 4.0), drop=Pose2D(2.0, 4.5), dwell_s=1.0)
    bb.task_id = "k-1"
    shelf_leaf = find(root, "GoToShelf")
    loop = Loop(sim, root)
    assert loop.run(5.0, until=lambda: shelf_leaf.status == Status.RUNNING)
    old = shelf_leaf.goal_id  # type: ignore[attr-defined]
    bb.pick = PickTask("k-2", shelf=Pose2D(2.0, 4.0, 1.57), drop=Pose2D(5.0, 2.0), dwell_s=1.0)
    bb.task_id = "k-2"
    loop.tick()
    assert b.goal_state(old).status is GoalStatus.CANCELED
    assert shelf_leaf.goal == NavigateToPose(Pose2D(2.0, 4.0, 1.57))  # type: ignore[attr-defined]
    assert loop.run(60.0, until=lambda: bb.picks_done == 1)
    assert pose_of(sim, NS).distance_to(Pose2D(5.0, 2.0)) <= sim.params.goal_tolerance + 0.01
