"""World-level behavior of the simulator: several robots, contacts, faults, battery, ids,
determinism, trajectories, the backend adapter and the planner."""

from __future__ import annotations

import math

import pytest
from sim_testworld import advance, corridor_grid, make_sim, room_grid, run_goal

import sim.planner as planner_module
from fleet.errors import BackendError
from fleet.maps import OCCUPIED, OccupancyGrid
from fleet.navigation import NavigationBackend
from fleet.robots import RobotSpec
from fleet.types import (
    DriveOnHeading,
    ErrorCode,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Wait,
)
from sim.backend import NamespacedBackend
from sim.planner import GridPlanner


def _pose(sim, ns: str) -> Pose2D:
    pose = sim.robot_state(ns).pose
    assert pose is not None
    return pose


# -- several robots ----------------------------------------------------------------------


def _drive_head_on(sim) -> tuple[str, str, float]:
    y = _pose(sim, "/a").y
    ga = sim.send_goal("/a", NavigateToPose(Pose2D(8.5, y, 0.0)))
    gb = sim.send_goal("/b", NavigateToPose(Pose2D(1.5, y, math.pi)))
    min_gap = math.inf
    while sim.clock.now() < 30.0 and not (
        sim.goal_state(ga).status.terminal and sim.goal_state(gb).status.terminal
    ):
        sim.step()
        min_gap = min(min_gap, _pose(sim, "/a").distance_to(_pose(sim, "/b")))
    return ga, gb, min_gap


def test_robots_meeting_head_on_in_the_open_keep_right_and_pass() -> None:
    sim = make_sim(
        {"/a": Pose2D(1.5, 4.0, 0.0), "/b": Pose2D(8.5, 4.0, math.pi)},
        grid=room_grid(10.0, 8.0, furnished=False),
    )
    ga, gb, min_gap = _drive_head_on(sim)
    assert sim.goal_state(ga).status is GoalStatus.SUCCEEDED
    assert sim.goal_state(gb).status is GoalStatus.SUCCEEDED
    assert min_gap >= 2 * sim.params.model.radius
    assert sim.collisions == 0
    # each kept to its right: /a (driving +x) dipped below y = 4, /b (driving -x) went above
    assert min(y for _, _, y in sim.trajectory("/a")) < 3.8
    assert max(y for _, _, y in sim.trajectory("/b")) > 4.2


def test_robots_meeting_head_on_in_a_corridor_stop_instead_of_passing_through() -> None:
    sim = make_sim(
        {"/a": Pose2D(1.5, 0.7, 0.0), "/b": Pose2D(8.5, 0.7, math.pi)},
        grid=corridor_grid(),
        stuck_time_s=3.0,
    )
    ga, gb, min_gap = _drive_head_on(sim)
    assert min_gap >= 2 * sim.params.model.radius
    assert _pose(sim, "/a").x < _pose(sim, "/b").x, "they did not pass through each other"
    assert sim.collisions == 0
    for gid, ns in ((ga, "/a"), (gb, "/b")):
        state = sim.goal_state(gid)
        assert state.status is GoalStatus.ABORTED
        assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
        assert sim.robot_state(ns).stuck


def test_robot_following_another_in_a_corridor_keeps_its_distance_and_both_arrive() -> None:
    sim = make_sim(
        {"/lead": Pose2D(3.0, 0.7, 0.0), "/follow": Pose2D(1.5, 0.7, 0.0)},
        grid=corridor_grid(12.0),
    )
    g1 = sim.send_goal("/lead", NavigateToPose(Pose2D(10.0, 0.7, 0.0)))
    sim.set_fault("/lead", "stalled")
    g2 = sim.send_goal("/follow", NavigateToPose(Pose2D(8.5, 0.7, 0.0)))
    advance(sim, 4.0)
    gap = _pose(sim, "/lead").distance_to(_pose(sim, "/follow"))
    assert 0.6 <= gap < 0.9  # waited behind the stalled robot
    sim.set_fault("/lead", None)
    assert sim.run_until(
        lambda: sim.goal_state(g1).status.terminal and sim.goal_state(g2).status.terminal, 40.0
    )
    assert sim.goal_state(g1).status is GoalStatus.SUCCEEDED
    assert sim.goal_state(g2).status is GoalStatus.SUCCEEDED
    assert sim.collisions == 0


def test_goal_ringed_by_parked_robots_fails_to_make_progress_instead_of_running_forever() -> None:
    goal = Pose2D(6.0, 4.0, 0.0)
    ring = {
        f"/p{i}": Pose2D(goal.x + 0.75 * math.cos(a), goal.y + 0.75 * math.sin(a))
        for i, a in enumerate((0.0, 1.57, 3.14, 4.71))
    }
    sim = make_sim(
        {"/r1": Pose2D(1.5, 4.0, 0.0), **ring}, grid=room_grid(12.0, 8.0, furnished=False), stuck_time_s=3.0
    )
    state = run_goal(sim, "/r1", NavigateToPose(goal), timeout_s=60.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    assert sim.collisions == 0


def test_contact_is_counted_once_per_touching_episode() -> None:
    sim = make_sim({"/a": Pose2D(2.0, 2.0, math.pi), "/b": Pose2D(2.5, 2.0, 0.0), "/c": Pose2D(6.0, 6.0)})
    advance(sim, 1.0)
    assert sim.collisions == 1
    assert len(sim.collision_events) == 1
    t, a, b, x, y = sim.collision_events[0]
    assert (a, b) == ("/a", "/b") and t == pytest.approx(0.05)
    assert (x, y) == pytest.approx((2.25, 2.0))
    assert sim.robot_state("/a").collisions == 1 and sim.robot_state("/b").collisions == 1
    assert sim.robot_state("/c").collisions == 0
    # they drive apart (each faces away from the other), then are placed in contact again
    assert run_goal(sim, "/a", DriveOnHeading(0.5, speed_mps=0.3)).status is GoalStatus.SUCCEEDED
    advance(sim, 1.0)
    assert sim.collisions == 1
    sim.set_fault("/b", "stalled")
    # /a comes back; the reactive stop keeps it from touching the stalled /b
    run_goal(sim, "/a", NavigateToPose(Pose2D(2.1, 2.0, math.pi)), timeout_s=15.0)
    assert sim.collisions == 1


def test_stalled_robot_with_nav_goal_is_reported_stuck_then_recovers() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)}, stuck_time_s=4.0)
    sim.set_fault("/r1", "stalled")
    gid = sim.send_goal("/r1", NavigateToPose(Pose2D(4.0, 2.0)))
    advance(sim, 3.0)
    assert not sim.robot_state("/r1").stuck
    advance(sim, 1.5)
    assert sim.robot_state("/r1").stuck
    assert sim.goal_state(gid).error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    sim.set_fault("/r1", None)
    assert run_goal(sim, "/r1", NavigateToPose(Pose2D(4.0, 2.0))).status is GoalStatus.SUCCEEDED
    assert not sim.robot_state("/r1").stuck


def test_unknown_fault_is_a_backend_error() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)})
    with pytest.raises(BackendError, match="unknown fault"):
        sim.set_fault("/r1", "on fire")


# -- battery -----------------------------------------------------------------------------


def test_battery_drains_with_distance_and_time_and_charges_at_a_charger() -> None:
    charger = Pose2D(2.0, 6.0, 0.0)
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)}, chargers=(charger,))
    b = sim.params.battery
    advance(sim, 10.0)
    idle = sim.robot_state("/r1")
    assert idle.battery == pytest.approx(1.0 - 10.0 * b.drain_per_s)
    assert not idle.charging
    assert run_goal(sim, "/r1", NavigateToPose(charger)).status is GoalStatus.SUCCEEDED
    arrived = sim.robot_state("/r1")
    assert (
        arrived.battery < idle.battery - b.drain_per_m * arrived.distance_m
    )  # distance and time cost charge
    advance(sim, 1.0)
    after = sim.robot_state("/r1")
    assert after.charging and after.battery > arrived.battery
    level = after.battery
    advance(sim, 5.0)
    assert sim.robot_state("/r1").battery == pytest.approx(min(1.0, level + 5.0 * b.charge_per_s))
    advance(sim, 60.0)
    assert sim.robot_state("/r1").battery == 1.0
    assert sim.robot_state("/r1").charging
    sim.send_goal("/r1", NavigateToPose(Pose2D(2.0, 3.0)))
    advance(sim, 2.0)
    assert not sim.robot_state("/r1").charging


def test_empty_battery_cannot_move_and_navigation_fails_to_progress() -> None:
    sim = make_sim({}, stuck_time_s=2.0)
    sim.add_robot(RobotSpec("r1", "/r1", Pose2D(2.0, 2.0), battery=0.0))
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(4.0, 2.0)), timeout_s=10.0)
    assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    assert sim.robot_state("/r1").distance_m == 0.0
    assert sim.robot_state("/r1").stuck


# -- ids, errors, backend ----------------------------------------------------------------


def test_goal_ids_are_namespaced_and_never_reused() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0), "/r2": Pose2D(2.0, 4.0)})
    ids = [sim.send_goal("/r1", Wait(1.0)) for _ in range(3)] + [sim.send_goal("/r2", Wait(1.0))]
    assert ids == ["/r1#1", "/r1#2", "/r1#3", "/r2#1"]
    assert [sim.goal_state(i).status for i in ids[:2]] == [GoalStatus.ABORTED] * 2
    with pytest.raises(KeyError):
        sim.goal_state("/r1#99")
    sim.cancel_goal("/r1#99")  # unknown: no-op


def test_add_robot_rejects_occupied_start_and_duplicate_namespace() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)})
    with pytest.raises(BackendError, match="not free"):
        sim.add_robot(RobotSpec("r2", "/r2", Pose2D(5.5, 2.0)))
    with pytest.raises(BackendError, match="not free"):
        sim.add_robot(RobotSpec("r2", "/r2", Pose2D(0.1, 2.0)))
    with pytest.raises(BackendError, match="already"):
        sim.add_robot(RobotSpec("r1", "/r1", Pose2D(3.0, 3.0)))
    with pytest.raises(BackendError):
        sim.send_goal("/ghost", Wait(1.0))
    assert sim.namespaces == ["/r1"]


def test_backend_is_a_navigation_backend_delegating_to_the_simulator() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0), "/r2": Pose2D(2.0, 4.0)})
    b = sim.backend("/r2")
    assert isinstance(b, NamespacedBackend)
    assert isinstance(b, NavigationBackend)
    assert b.namespace == "/r2" and sim.backend("/r2") is b
    gid = b.send_goal(NavigateThroughPoses((Pose2D(3.0, 4.0),)))
    assert gid.startswith("/r2#")
    sim.run_until(lambda: b.goal_state(gid).status.terminal, 20.0)
    assert b.goal_state(gid).status is GoalStatus.SUCCEEDED
    assert b.robot_state() == sim.robot_state("/r2")
    assert _pose(sim, "/r1") == Pose2D(2.0, 2.0, 0.0)


def test_trajectory_is_sampled_every_half_second() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)})
    sim.send_goal("/r1", NavigateToPose(Pose2D(4.0, 2.0)))
    advance(sim, 3.0)
    traj = sim.trajectory("/r1")
    assert [round(t, 6) for t, _, _ in traj] == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    xs = [x for _, x, _ in traj]
    assert xs == sorted(xs) and xs[-1] > 3.0


def test_trajectories_keep_the_recent_samples_of_a_long_run(monkeypatch: pytest.MonkeyPatch) -> None:
    import sim.simulator

    monkeypatch.setattr(sim.simulator, "TRAJECTORY_KEEP_S", 200.0)  # 400 samples
    sim_ = make_sim({"/r1": Pose2D(2.0, 2.0)})
    advance(sim_, 100.0)
    sim_.add_robot(RobotSpec("r2", "/r2", Pose2D(2.0, 4.0)))
    advance(sim_, 300.0)
    for ns, t_added in (("/r1", 0.0), ("/r2", 100.0)):
        traj = sim_.trajectory(ns)
        assert 400 <= len(traj) < 400 + 256 and traj[0][0] > t_added  # the oldest were dropped
        assert traj[-1][0] == pytest.approx(400.0)
        assert [round(t2 - t1, 6) for (t1, _, _), (t2, _, _) in zip(traj, traj[1:], strict=False)] == [
            0.5
        ] * (len(traj) - 1)


def test_run_until_reports_timeout_in_sim_time() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)})
    assert not sim.run_until(lambda: False, 2.0)
    assert sim.clock.now() == pytest.approx(2.0)
    assert sim.run_until(lambda: True, 2.0)
    assert sim.clock.now() == pytest.approx(2.0)


def _scenario() -> list[list[tuple[float, float, float]]]:
    sim = make_sim({f"/r{i}": Pose2D(1.5, 1.5 + 1.2 * i, 0.0) for i in range(5)})
    for i, ns in enumerate(sim.namespaces):
        sim.send_goal(ns, NavigateToPose(Pose2D(9.0, 7.0 - 1.2 * i, 1.0)))
    advance(sim, 25.0)
    return [sim.trajectory(ns) for ns in sim.namespaces]


def test_same_inputs_give_identical_trajectories() -> None:
    assert _scenario() == _scenario()


def test_thirty_robots_crossing_a_room_all_make_progress() -> None:
    """(Steps per second of this scene: ``python bench/bench_sim.py --scenes``.)"""
    sim = make_sim(
        {f"/r{i}": Pose2D(1.0 + (i % 5) * 1.0, 1.0 + (i // 5) * 1.0, 0.0) for i in range(30)},
        grid=room_grid(40.0, 30.0, furnished=False),
    )
    for i, ns in enumerate(sim.namespaces):
        sim.send_goal(ns, NavigateToPose(Pose2D(30.0 + (i % 5) * 1.0, 1.0 + (i // 5) * 1.0, 0.0)))
    advance(sim, 10.0)
    assert all(sim.robot_state(ns).distance_m > 3.0 for ns in sim.namespaces)
    assert sim.collisions == 0


# -- planner -------------------------------------------------------------------------------


def _warehouse() -> OccupancyGrid:
    g = room_grid(40.0, 30.0, furnished=False)
    for k in range(8):  # shelf rows with aisles between them and cross aisles at both ends
        x0 = 40 + k * 45
        g.cells[30:270, x0 : x0 + 15] = OCCUPIED
    g.cells[150:152, 40:360] = OCCUPIED  # one long wall across the middle of the shelves
    return g


def test_planner_on_a_40_by_30_m_warehouse_plans_collision_free_paths() -> None:
    """(Planning times on this map: ``python bench/bench_sim.py --scenes``.)"""
    g = _warehouse()
    planner = GridPlanner(g, 0.3)
    pairs = [((2.0, 2.0), (38.0, 28.0)), ((6.0, 10.0), (34.0, 20.0)), ((2.0, 15.0), (38.5, 15.0))]
    results = []
    for start, goal in pairs:
        res = planner.plan(start, goal)
        results.append(res)
        assert res.ok, res.error_msg
        assert res.path[0] == start and res.path[-1] == goal
        for a, b in zip(res.path, res.path[1:], strict=False):
            assert planner.segment_free(a, b, planner.footprint)
    assert planner.plan(*pairs[0]) is results[0]  # cached


def test_planner_uses_a_straight_line_when_it_is_free() -> None:
    planner = GridPlanner(room_grid(), 0.3)
    assert planner.plan((1.0, 1.0), (4.0, 4.0)).path == ((1.0, 1.0), (4.0, 4.0))


def test_planner_reports_start_occupied() -> None:
    planner = GridPlanner(room_grid(), 0.3)
    res = planner.plan((5.5, 2.0), (2.0, 2.0))
    assert res.error_code == ErrorCode.START_OCCUPIED
    assert "(5.50, 2.00)" in res.error_msg


def test_planner_does_not_pass_through_a_thin_wall_into_a_small_closed_box() -> None:
    """Regression: the leg from the last coarse cell to a goal inside a 1 x 1 m box with
    0.1 m walls went through the wall (the goal's own coarse cell is blocked by the inflation)."""
    g = room_grid(12.0, 8.0, furnished=False)
    g.cells[45:56, 65] = g.cells[45:56, 75] = OCCUPIED
    g.cells[45, 65:76] = g.cells[55, 65:76] = OCCUPIED
    planner = GridPlanner(g, 0.3)
    assert planner.footprint_free(7.0, 5.0)  # the robot fits inside the box ...
    res = planner.plan((2.0, 3.0), (7.0, 5.0))
    assert res.error_code == ErrorCode.NO_VALID_PATH, res.path  # ... but cannot get in
    ok = planner.plan((2.0, 3.0), (9.0, 6.5))
    assert ok.ok and all(
        planner.segment_free(a, b, planner.footprint) for a, b in zip(ok.path, ok.path[1:], strict=False)
    )


def test_robot_boxed_in_by_obstacles_in_the_open_is_stuck_and_aborts_105() -> None:
    sim = make_sim(
        {"/r1": Pose2D(6.0, 4.0, 0.0)}, grid=room_grid(12.0, 8.0, furnished=False), stuck_time_s=3.0
    )
    for k in range(8):
        a = k * math.pi / 4
        sim.add_obstacle(6.0 + 0.75 * math.cos(a), 4.0 + 0.75 * math.sin(a), 0.3)
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(10.0, 4.0, 0.0)), timeout_s=3 * 3.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    assert sim.robot_state("/r1").stuck


def test_robot_whose_goal_is_covered_by_an_obstacle_aborts_105_instead_of_waiting_forever() -> None:
    sim = make_sim(
        {"/r1": Pose2D(2.0, 4.0, 0.0)}, grid=room_grid(12.0, 8.0, furnished=False), stuck_time_s=3.0
    )
    sim.add_obstacle(8.0, 4.0, 1.0)
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(8.0, 4.0, 0.0)), timeout_s=40.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    assert sim.collisions == 0
    assert _pose(sim, "/r1").distance_to(Pose2D(8.0, 4.0)) >= 1.3 - 1e-6


def test_a_fleet_of_400_robots_drives_to_its_goals_without_contacts() -> None:
    """(Steps per second of this scene: ``python bench/bench_sim.py --scenes``.)"""
    sim = make_sim(
        {f"/r{i}": Pose2D(1.0 + (i % 38) * 1.0, 1.0 + (i // 38) * 1.0, 0.0) for i in range(400)},
        grid=room_grid(40.0, 30.0, furnished=False),
    )
    for i, ns in enumerate(sim.namespaces):
        sim.send_goal(ns, NavigateToPose(Pose2D(1.0 + (i % 38) * 1.0, 16.0 + (i // 38) * 1.0, 0.0)))
    advance(sim, 6.0)
    assert sum(sim.robot_state(ns).distance_m for ns in sim.namespaces) > 400 * 1.5
    assert sim.collisions == 0


def test_planner_keeps_at_most_path_cache_cell_paths_and_plans_the_same_after_forgetting(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A fleet that keeps driving starts goals from ever new cells: the coarse path cache is
    bounded (the least recently used path goes), and a forgotten path is planned again the same."""
    monkeypatch.setattr(planner_module, "PATH_CACHE", 4)
    planner = GridPlanner(room_grid(), 0.3)
    goal = (8.0, 1.5)  # behind the shelf (x 5-6, y 0-5): every plan needs the A* search
    starts = [(3.0 + 0.35 * i, 1.0 + 0.35 * j) for i in range(3) for j in range(4)]
    first = [planner.plan(s, goal).path for s in starts]
    assert all(len(p) > 2 for p in first)
    assert planner.cached_paths == 4
    again = GridPlanner(room_grid(), 0.3)  # the other way round: other paths forgotten
    assert [again.plan(s, goal).path for s in reversed(starts)][::-1] == first
    assert again.cached_paths == 4
