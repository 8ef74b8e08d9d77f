"""The SUMO backend on real libsumo: navigation, cancel, preemption, deadlock and collision
signals, timed no-op recoveries and the one-world-per-process rule."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import networkx as nx
import pytest

from fleet.clock import SimClock
from fleet.errors import BackendError
from fleet.navigation import NavigationBackend
from fleet.robots import RobotSpec, SimParams
from fleet.types import (
    BackUp,
    DriveOnHeading,
    ErrorCode,
    FollowWaypoints,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
)
from sim.sumo.net import grid_roadmap

pytestmark = pytest.mark.sumo
pytest.importorskip("libsumo")
pytest.importorskip("sumo")

from sim.sumo.backend import active_world  # noqa: E402
from sim.sumo.world import SumoWorld  # noqa: E402

PARAMS = replace(SimParams(), step_s=0.1)
H = 0.45  # half lane width for the default robot (radius 0.3): lanes lie H m right of the aisle
SPACING = 12.0


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("sumo-cache")


@pytest.fixture(autouse=True)
def _no_leftover_world() -> Iterator[None]:
    yield
    w = active_world()
    if w is not None:
        w.close()


def make_world(
    cache: Path, robots: dict[str, Pose2D], roadmap: nx.Graph | None = None, **kw: Any
) -> SumoWorld:
    specs = [RobotSpec(ns.strip("/"), ns, p) for ns, p in robots.items()]
    params = kw.pop("params", PARAMS)
    world = SumoWorld(
        roadmap if roadmap is not None else grid_roadmap(3, 3, SPACING),
        specs,
        params,
        SimClock(),
        cache_dir=cache,
        **kw,
    )
    world.step()  # insert the vehicles
    return world


def east(x: float, row: int = 0) -> Pose2D:
    """A pose on the eastbound lane of grid row ``row``."""
    return Pose2D(x, row * SPACING - H, 0.0)


def north(y: float, col: int = 0) -> Pose2D:
    """A pose on the northbound lane of grid column ``col``."""
    return Pose2D(col * SPACING + H, y, math.pi / 2)


def run(world: SumoWorld, ids: dict[str, str], timeout_s: float) -> None:
    world.run_until(lambda: all(world.goal_state(g).status.terminal for g in ids.values()), timeout_s)


@pytest.mark.parametrize("internal_links", [False, True])
def test_robots_drive_navigate_through_poses_to_the_end_without_collisions(
    cache: Path, internal_links: bool
) -> None:
    starts = {"/r1": east(2.0), "/r2": north(2.0, col=2), "/r3": east(3.0, row=2), "/r4": north(3.0, col=1)}
    goals = {
        "/r1": (east(8.0, row=1), north(20.0, col=2)),
        "/r2": (east(6.0, row=1), Pose2D(3.0, 2 * SPACING + H, math.pi)),
        "/r3": (north(8.0, col=1), east(9.0, row=0)),
        "/r4": (east(18.0, row=1), north(4.0, col=0), east(5.0, row=0)),
    }
    with make_world(cache, starts, internal_links=internal_links) as world:
        backends = {ns: world.backend(ns) for ns in starts}
        assert all(isinstance(b, NavigationBackend) for b in backends.values())
        ids = {ns: backends[ns].send_goal(NavigateThroughPoses(goals[ns])) for ns in starts}
        run(world, ids, 150.0)
        for ns, gid in ids.items():
            state = world.goal_state(gid)
            assert state.status is GoalStatus.SUCCEEDED, (ns, state.error_msg)
            assert state.feedback.number_of_poses_remaining == 0
            world.run_until(lambda: False, 0.5)
            pose = backends[ns].robot_state().pose
            assert pose is not None and pose.distance_to(goals[ns][-1]) < 0.1, (ns, pose)
        assert world.collisions == 0
        assert world.teleports == 0
        traj = world.trajectory("/r1")
        assert traj[0][1:] == pytest.approx((2.0, -H)) and len(traj) > 10
        assert traj[1][0] == pytest.approx(0.5)
        if not internal_links:  # poses follow the roadmap edges: at a junction a robot only
            # switches sides (at most one lane pair's width), it does not jump across it
            for ns in starts:
                tr = world.trajectory(ns)
                steps = [math.dist(a[1:], b[1:]) for a, b in zip(tr, tr[1:], strict=False)]
                assert max(steps) <= 0.5 * PARAMS.model.max_linear_speed + 2 * H + 0.05, ns
        rs = backends["/r1"].robot_state()
        assert rs.distance_m > 20.0 and rs.battery < 1.0 and rs.collisions == 0 and not rs.stuck


def test_feedback_counts_down_and_follow_waypoints_reports_the_waypoint(cache: Path) -> None:
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        gid = b.send_goal(FollowWaypoints((east(6.0), east(9.0), north(5.0, col=1))))
        world.run_until(lambda: False, 2.0)
        fb1 = b.goal_state(gid).feedback
        world.run_until(lambda: b.goal_state(gid).feedback.current_waypoint == 1, 10.0)
        fb2 = b.goal_state(gid).feedback
        assert fb2.current_waypoint == 1
        assert fb1.distance_remaining_m is not None and fb2.distance_remaining_m is not None
        assert fb2.distance_remaining_m < fb1.distance_remaining_m
        assert fb2.estimated_time_remaining_s == pytest.approx(
            fb2.distance_remaining_m / PARAMS.model.max_linear_speed
        )
        run(world, {"r1": gid}, 60.0)
        assert b.goal_state(gid).status is GoalStatus.SUCCEEDED


def test_a_pose_behind_the_robot_on_its_own_lane_is_reached_by_looping_round(cache: Path) -> None:
    with make_world(cache, {"/r1": east(6.0)}) as world:
        b = world.backend("/r1")
        gid = b.send_goal(NavigateToPose(east(3.0)))
        run(world, {"r1": gid}, 120.0)
        state = b.goal_state(gid)
        assert state.status is GoalStatus.SUCCEEDED, state.error_msg
        assert b.robot_state().distance_m > SPACING  # went round (two U-turns), never reversed
        assert b.robot_state().pose.distance_to(east(3.0)) < 0.1  # type: ignore[union-attr]


@pytest.mark.parametrize("internal_links", [False, True])
def test_cancel_ends_canceled_at_once_and_the_robot_brakes_to_rest(cache: Path, internal_links: bool) -> None:
    with make_world(cache, {"/r1": east(2.0)}, internal_links=internal_links) as world:
        b = world.backend("/r1")
        gid = b.send_goal(NavigateToPose(east(9.0, row=1)))
        world.run_until(lambda: False, 3.0)
        moving = b.robot_state()
        assert moving.linear_velocity > 0.5
        b.cancel_goal(gid)
        b.cancel_goal(gid)  # idempotent
        assert b.goal_state(gid).status is GoalStatus.CANCELED
        world.run_until(lambda: False, 2.0)
        rest = b.robot_state()
        assert rest.linear_velocity == 0.0
        braking = rest.pose.distance_to(moving.pose)  # type: ignore[union-attr,arg-type]
        v = moving.linear_velocity
        assert braking <= v * v / (2 * PARAMS.model.max_linear_accel) + v * PARAMS.step_s + 0.05
        world.run_until(lambda: False, 5.0)
        assert b.robot_state().pose == rest.pose
        assert b.goal_state(gid).status is GoalStatus.CANCELED


def test_a_new_goal_preempts_the_running_one(cache: Path) -> None:
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        first = b.send_goal(NavigateToPose(east(9.0, row=2)))
        world.run_until(lambda: False, 2.0)
        second = b.send_goal(NavigateToPose(north(6.0, col=1)))
        old = b.goal_state(first)
        assert old.status is GoalStatus.ABORTED and second in old.error_msg
        run(world, {"r1": second}, 60.0)
        assert b.goal_state(second).status is GoalStatus.SUCCEEDED
        assert b.robot_state().pose.distance_to(north(6.0, col=1)) < 0.1  # type: ignore[union-attr]
        assert b.goal_state(first).status is GoalStatus.ABORTED  # a stale id never completes


def test_a_blocking_robot_makes_sumo_teleport_and_that_is_a_deadlock_signal(cache: Path) -> None:
    # r2 holds on the lane ahead of r1 (park_idle=False: idle robots block their lane)
    with make_world(
        cache, {"/r1": east(2.0), "/r2": east(6.0)}, park_idle=False, time_to_teleport=2.0
    ) as world:
        b1, b2 = world.backend("/r1"), world.backend("/r2")
        hold = b2.send_goal(Wait(60.0))
        gid = b1.send_goal(NavigateToPose(east(9.0)))
        world.run_until(lambda: b1.goal_state(gid).status.terminal, 30.0)
        state = b1.goal_state(gid)
        assert state.status is GoalStatus.ABORTED
        assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
        assert "teleported" in state.error_msg
        assert world.teleports == 1 and world.teleports_of("/r1") == 1
        assert b1.robot_state().stuck
        assert b2.goal_state(hold).status is GoalStatus.EXECUTING
        # the next goal clears the stuck flag
        b1.send_goal(Wait(0.1))
        assert not b1.robot_state().stuck


def test_collisions_are_counted_once_per_contact_for_both_robots(cache: Path) -> None:
    import libsumo

    with make_world(
        cache, {"/r1": east(2.0), "/r2": east(6.0)}, park_idle=False, time_to_teleport=-1
    ) as world:
        b1, b2 = world.backend("/r1"), world.backend("/r2")
        gid = b1.send_goal(NavigateToPose(east(9.0)))
        world.step()
        libsumo.vehicle.setSpeedMode("r1", 0)  # a faulty robot: ignores the one ahead
        world.run_until(lambda: world.collisions > 0, 20.0)
        world.run_until(lambda: False, 1.0)  # still overlapping: the same contact
        assert world.collisions == 1
        assert b1.robot_state().collisions == 1 and b2.robot_state().collisions == 1
        ((t, a, b, x, y),) = world.collision_events
        assert {a, b} == {"/r1", "/r2"} and 0.0 < t < 25.0
        assert 3.0 < x < 9.0 and y == pytest.approx(-H)
        assert b1.goal_state(gid).status in (GoalStatus.EXECUTING, GoalStatus.SUCCEEDED)


def test_only_one_sumo_world_at_a_time(cache: Path) -> None:
    world = make_world(cache, {"/r1": east(2.0)})
    with pytest.raises(BackendError, match="only one SumoWorld"):
        make_world(cache, {"/r1": east(2.0)})
    assert not world.closed
    world.close()
    world.close()  # idempotent
    with make_world(cache, {"/r1": east(2.0)}) as again:
        assert again.backend("/r1").robot_state().pose is not None


def test_closing_aborts_running_goals_as_server_unavailable(cache: Path) -> None:
    world = make_world(cache, {"/r1": east(2.0)})
    b = world.backend("/r1")
    gid = b.send_goal(NavigateToPose(east(9.0, row=1)))
    world.run_until(lambda: False, 1.0)
    world.close()
    state = b.goal_state(gid)
    assert state.status is GoalStatus.ABORTED and state.error_code == ErrorCode.SERVER_UNAVAILABLE
    with pytest.raises(BackendError, match="closed"):
        b.send_goal(Wait(1.0))


def test_recoveries_are_timed_no_ops_and_bad_inputs_abort(cache: Path) -> None:
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        start = b.robot_state().pose
        spin = b.send_goal(Spin(math.pi / 2))
        expected = (math.pi / 2) / PARAMS.model.max_angular_speed
        world.run_until(lambda: b.goal_state(spin).status.terminal, 10.0)
        assert b.goal_state(spin).status is GoalStatus.SUCCEEDED
        assert world.clock.now() == pytest.approx(0.1 + expected, abs=0.11)
        assert b.goal_state(spin).feedback.angular_distance_traveled == 0.0
        assert b.robot_state().pose.distance_to(start) < 1e-6  # type: ignore[union-attr,arg-type]
        assert b.robot_state().pose.theta == pytest.approx(start.theta)  # type: ignore[union-attr,union-attr]
        backup = b.send_goal(BackUp(0.3, speed_mps=0.15))
        run(world, {"r1": backup}, 5.0)
        assert b.goal_state(backup).status is GoalStatus.SUCCEEDED
        bad = b.send_goal(BackUp(-1.0))
        assert b.goal_state(bad).error_code == ErrorCode.BACKUP_INVALID_INPUT
        slow = b.send_goal(DriveOnHeading(5.0, speed_mps=0.1, time_allowance_s=2.0))
        run(world, {"r1": slow}, 5.0)
        state = b.goal_state(slow)
        assert state.status is GoalStatus.ABORTED and state.error_code == ErrorCode.DRIVE_TIMEOUT
        assert b.goal_state(b.send_goal(NavigateThroughPoses(()))).status is GoalStatus.REJECTED


def test_goals_that_cannot_start_end_as_on_the_simulator(cache: Path) -> None:
    """The goal semantics shared with the simulator (sim/goals.py)."""
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        empty = b.goal_state(b.send_goal(FollowWaypoints(())))
        assert empty.status is GoalStatus.ABORTED and empty.error_code == ErrorCode.WAYPOINT_UNKNOWN
        spin = b.goal_state(b.send_goal(Spin(float("nan"))))
        assert spin.status is GoalStatus.ABORTED and spin.error_code == ErrorCode.SPIN_UNKNOWN
        drive = b.goal_state(b.send_goal(DriveOnHeading(1.0, speed_mps=float("nan"))))
        assert drive.status is GoalStatus.ABORTED and drive.error_code == ErrorCode.DRIVE_INVALID_INPUT
        wait = b.send_goal(Wait(5.0))
        with pytest.raises(BackendError, match="not a navigation goal"):
            b.send_goal(object())  # type: ignore[arg-type]
        world.run_until(lambda: False, 1.0)
        assert b.goal_state(wait).status is GoalStatus.EXECUTING
        assert wait == "/r1#4" and b.send_goal(Wait(1.0)) == "/r1#5"


def test_wait_while_driving_holds_on_the_lane(cache: Path) -> None:
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        b.send_goal(NavigateToPose(east(9.0, row=1)))
        world.run_until(lambda: False, 3.0)
        wait = b.send_goal(Wait(3.0))
        world.run_until(lambda: False, 2.0)
        assert b.robot_state().linear_velocity == 0.0
        assert b.goal_state(wait).status is GoalStatus.EXECUTING
        assert 0.0 < (b.goal_state(wait).feedback.time_left_s or 0.0) <= 1.0 + 1e-6
        run(world, {"r1": wait}, 3.0)
        assert b.goal_state(wait).status is GoalStatus.SUCCEEDED


def test_poses_far_from_lanes_or_on_an_island_abort_with_planner_codes(cache: Path) -> None:
    g = grid_roadmap(2, 2, SPACING)
    g.add_node("i1", pos=(40.0, 0.0))
    g.add_node("i2", pos=(50.0, 0.0))
    g.add_edge("i1", "i2")
    with make_world(cache, {"/r1": east(2.0)}, roadmap=g) as world:
        b = world.backend("/r1")
        far = b.goal_state(b.send_goal(NavigateToPose(Pose2D(6.0, 30.0, 0.0))))
        assert far.status is GoalStatus.ABORTED and far.error_code == ErrorCode.GOAL_OUTSIDE_MAP
        assert "from the nearest SUMO lane" in far.error_msg
        island = b.goal_state(b.send_goal(NavigateToPose(Pose2D(45.0, -H, 0.0))))
        assert island.status is GoalStatus.ABORTED and island.error_code == ErrorCode.NO_VALID_PATH


def test_a_net_xml_roadmap_drives_on_that_network(cache: Path, tmp_path: Path) -> None:
    from fleet.roadmap.graph import Roadmap
    from fleet.roadmap.netxml import read_network
    from sim.sumo.net import build_network, settings_for_robot

    made = build_network(grid_roadmap(2, 2, SPACING), settings_for_robot(0.3, 1.0), tmp_path)
    g = read_network(made.net_path)
    roadmap = Roadmap.from_graph(g)
    with make_world(cache, {"/r1": east(2.0)}, roadmap=roadmap, net_file=made.net_path) as world:
        assert world.network.net_path == made.net_path
        b = world.backend("/r1")
        gid = b.send_goal(NavigateToPose(north(8.0, col=1)))
        run(world, {"r1": gid}, 60.0)
        assert b.goal_state(gid).status is GoalStatus.SUCCEEDED


def test_battery_drains_while_driving_and_charges_at_a_charger(cache: Path) -> None:
    params = replace(PARAMS, chargers=(Pose2D(9.0, -1.0, 0.0),))
    with make_world(cache, {"/r1": east(2.0, row=1)}, params=params) as world:
        b = world.backend("/r1")
        gid = b.send_goal(NavigateToPose(east(9.0)))
        run(world, {"r1": gid}, 60.0)
        assert b.goal_state(gid).status is GoalStatus.SUCCEEDED
        low = b.robot_state()
        assert low.battery < 1.0 - PARAMS.battery.drain_per_m * 15
        world.run_until(lambda: False, 5.0)
        charged = b.robot_state()
        assert charged.charging
        assert charged.battery == pytest.approx(
            min(1.0, low.battery + 5.0 * PARAMS.battery.charge_per_s), abs=1e-3
        )


def test_same_seed_same_run(cache: Path) -> None:
    def once() -> list[tuple[float, float]]:
        with make_world(cache, {"/r1": east(2.0), "/r2": north(2.0, col=1)}) as world:
            b1, b2 = world.backend("/r1"), world.backend("/r2")
            b1.send_goal(NavigateThroughPoses((east(8.0, row=1), north(20.0, col=2))))
            b2.send_goal(NavigateToPose(east(3.0, row=1)))
            out = []
            for _ in range(20):
                world.run_until(lambda: False, 1.0)
                p1, p2 = b1.robot_state().pose, b2.robot_state().pose
                assert p1 is not None and p2 is not None
                out += [(p1.x, p1.y), (p2.x, p2.y)]
            return out

    assert once() == once()


def test_a_route_passing_the_last_pose_lane_twice_stops_on_the_second_pass(cache: Path) -> None:
    # y=6 then y=3 on the same northbound lane: the route passes that lane, loops round and
    # comes back; the stop must not catch the robot on the first pass
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        gid = b.send_goal(NavigateThroughPoses((north(6.0, col=1), north(3.0, col=1))))
        run(world, {"r1": gid}, 120.0)
        state = b.goal_state(gid)
        assert state.status is GoalStatus.SUCCEEDED, state.error_msg
        assert b.robot_state().distance_m > 2 * SPACING
        assert b.robot_state().pose.distance_to(north(3.0, col=1)) < 0.1  # type: ignore[union-attr]


def test_the_shipped_warehouse_patrols_on_sumo_through_the_runner_world() -> None:
    from fleet.config.loader import load_config
    from sim.sumo.backend import SumoRunnerWorld

    path = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"
    if not path.exists():
        pytest.skip(f"{path} not present")
    cfg = load_config(path)
    world = SumoRunnerWorld(cfg, list(cfg.robots), None)
    try:
        world.advance()
        ids = {}
        for i, spec in enumerate(cfg.robots):
            route = cfg.routes[i % len(cfg.routes)]
            ids[spec.namespace] = world.backend(spec.namespace).send_goal(
                NavigateThroughPoses(cfg.route_poses(route))
            )
        world.world.run_until(
            lambda: all(world.backend(ns).goal_state(g).status.terminal for ns, g in ids.items()), 300.0
        )
        for ns, gid in ids.items():
            state = world.backend(ns).goal_state(gid)
            assert state.status is GoalStatus.SUCCEEDED, (ns, state.error_msg)
        assert world.collisions() == 0 and world.world.teleports == 0
        assert world.collision_points() == []
        assert len(world.trajectory(cfg.robots[0].namespace) or []) > 10
    finally:
        world.close()


def test_a_goal_on_a_junction_centre_is_reached_at_the_lane_end_beside_it(cache: Path) -> None:
    with make_world(cache, {"/r1": east(2.0)}) as world:
        b = world.backend("/r1")
        goal = Pose2D(SPACING, SPACING, 0.0)  # junction g1_1, facing east
        gid = b.send_goal(NavigateToPose(goal))
        run(world, {"r1": gid}, 60.0)
        assert b.goal_state(gid).status is GoalStatus.SUCCEEDED
        pose = b.robot_state().pose
        assert pose is not None and pose.distance_to(goal) <= H + PARAMS.model.radius + 0.05
        assert abs(pose.theta) < 0.01


def test_snapped_poses_are_remembered_within_a_bound(cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Snapping a pose again answers from memory with the very lane point a scan of every
    lane gives; the memory is emptied when it holds ``NEAREST_KEPT`` poses."""
    from sim.sumo import lanes as lanes_mod

    monkeypatch.setattr(lanes_mod, "NEAREST_KEPT", 3)
    with make_world(cache, {"/r1": east(2.0)}) as world:
        index = world.lanes
        index._nearest.clear()
        poses = [(5.0, -H, 0.0), (SPACING, 5.0, math.pi / 2), (7.0, SPACING + H, math.pi), (1.0, 1.0, None)]
        for x, y, th in poses:
            first = index.nearest(x, y, th)
            assert first == index._scan(x, y, th)
            assert index.nearest(x, y, th) is first  # from memory
            assert len(index._nearest) <= 3
