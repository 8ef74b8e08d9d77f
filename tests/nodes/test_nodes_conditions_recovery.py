"""Conditions, the RecoveryNode / RoundRobin / RestartOnChange composites, on the real
simulator."""

from __future__ import annotations

from dataclasses import replace

import py_trees
import pytest
from nodes_world import BOX, CHARGER, RING_PLUG, Loop, make_ring_world, make_world, pose_of
from py_trees.common import Status

from fleet.types import GoalStatus, NavigateToPose, Pose2D
from nodes.blackboard import read_key, robot_blackboard
from nodes.conditions import BatteryLow, HasAssignment, IsLocalized, IsStuck, NearPose
from nodes.leaves import GoalAction, NavigateToPoseAction, WaitAction
from nodes.recovery import RecoveryNode, RestartOnChange, RoundRobin, recovery_actions

NS = "/robot1"


def test_battery_low_has_hysteresis(fast_battery) -> None:  # type: ignore[no-untyped-def]
    sim = make_world({NS: (Pose2D(2.0, 3.0), 0.35)}, battery=fast_battery)
    low = BatteryLow(sim.backend(NS), fast_battery.low, fast_battery.resume)
    low.tick_once()
    assert low.status == Status.FAILURE  # 0.35 >= low
    leaf = NavigateToPoseAction(sim.backend(NS), CHARGER)
    Loop(sim, leaf).run(30.0, until=lambda: leaf.status != Status.RUNNING)
    assert leaf.status == Status.SUCCESS
    assert sim.robot_state(NS).battery < fast_battery.low
    low.tick_once()
    assert low.status == Status.SUCCESS and low.latched
    sim.run_until(lambda: sim.robot_state(NS).battery > fast_battery.low + 0.1, 10.0)
    low.tick_once()
    assert low.status == Status.SUCCESS  # charging, above low, below resume: still low
    sim.run_until(lambda: sim.robot_state(NS).battery >= fast_battery.resume, 10.0)
    low.tick_once()
    assert low.status == Status.FAILURE and not low.latched
    with pytest.raises(ValueError):
        BatteryLow(sim.backend(NS), 0.9, 0.3)


def test_a_restarted_battery_guard_finishes_the_charge_under_way(fast_battery) -> None:  # type: ignore[no-untyped-def]
    """A guard that first sees its robot charging (its agent was restarted mid-charge) holds
    it on the charger until ``resume``; one that first sees it elsewhere does not latch."""
    sim = make_world(
        {NS: (CHARGER, 0.5), "/robot2": (Pose2D(2.0, 3.0), 0.5)},
        battery=replace(fast_battery, charge_per_s=0.01),
    )
    sim.step()  # the simulator has seen robot1 stand on the charger
    assert sim.robot_state(NS).charging and not sim.robot_state("/robot2").charging
    restarted = BatteryLow(sim.backend(NS), fast_battery.low, fast_battery.resume)
    restarted.tick_once()
    assert restarted.status == Status.SUCCESS and restarted.latched  # 0.5 >= low, but charging
    away = BatteryLow(sim.backend("/robot2"), fast_battery.low, fast_battery.resume)
    away.tick_once()
    assert away.status == Status.FAILURE
    sim.run_until(lambda: sim.robot_state(NS).battery >= fast_battery.resume, 60.0)
    restarted.tick_once()
    assert restarted.status == Status.FAILURE and not restarted.latched
    restarted.tick_once()  # only the first look latches: charging again later does not
    assert restarted.status == Status.FAILURE


def test_charge_threshold_grows_with_the_way_to_the_charger() -> None:
    """The trigger is the energy to reach a charger with a margin, not a fixed level: a robot
    far from its charger goes earlier, one beside it never later than ``low``; every level
    it leaves at still reaches the charger with ``reserve`` left after the budgeted wait."""
    from fleet.robots import BatteryModel

    m = BatteryModel()
    near, far = m.charge_threshold(2.0), m.charge_threshold(150.0)
    assert m.low <= m.charge_threshold(0.0) < near < far
    for d in (0.0, 10.0, 40.0, 150.0):
        trip = m.drain_per_m * d * m.detour + m.drain_per_s * (d * m.detour / m.cruise_mps + m.wait_s)
        assert m.charge_threshold(d) - trip >= m.reserve - 1e-12


def test_charge_line_is_the_threshold_as_a_line() -> None:
    """The event-driven scheduler checks the trigger for all robots at once as ``max(low, a + b
    * d)``: it must be the threshold itself, for default and unusual battery models."""
    from dataclasses import replace

    from fleet.robots import BatteryModel

    for m in (BatteryModel(), replace(BatteryModel(), reserve=0.02, margin=1.0, detour=1.5, wait_s=0.0)):
        a, b = m.charge_line()
        for d in (0.0, 0.5, 7.0, 40.0, 150.0, 900.0):
            assert max(m.low, a + b * d) == pytest.approx(m.charge_threshold(d), abs=1e-12)


def test_battery_low_follows_a_threshold(fast_battery) -> None:  # type: ignore[no-untyped-def]
    sim = make_world({NS: (Pose2D(2.0, 3.0), 0.6)}, battery=fast_battery)
    level = [0.5]
    low = BatteryLow(sim.backend(NS), fast_battery.low, fast_battery.resume, threshold=lambda: level[0])
    low.tick_once()
    assert low.status == Status.FAILURE  # 0.6 >= 0.5
    level[0] = 0.7  # e.g. the robot drove away from its charger
    low.tick_once()
    assert low.status == Status.SUCCESS and low.latched


def test_is_stuck_is_localized_near_pose() -> None:
    sim = make_world({NS: Pose2D(2.0, 3.0)}, stuck_time_s=1.0)
    b = sim.backend(NS)
    stuck, localized = IsStuck(b), IsLocalized(b)
    near = NearPose(b, read_key(NS, "charger"), 0.3)
    for node in (stuck, localized, near):
        node.tick_once()
    assert (stuck.status, localized.status, near.status) == (Status.FAILURE, Status.SUCCESS, Status.FAILURE)
    assert near.feedback_message == "no target pose"
    robot_blackboard(NS).charger = Pose2D(2.2, 3.1)
    near.tick_once()
    assert near.status == Status.SUCCESS
    sim.set_fault(NS, "localization_lost")
    sim.run_until(lambda: sim.robot_state(NS).pose_age_s > 1.0, 3.0)
    localized.tick_once()
    assert localized.status == Status.FAILURE
    sim.set_fault(NS, None)
    sim.step()
    localized.tick_once()
    assert localized.status == Status.SUCCESS
    sim.set_fault(NS, "stalled")
    b.send_goal(NavigateToPose(Pose2D(5.0, 3.0)))
    sim.run_until(lambda: sim.robot_state(NS).stuck, 3.0)
    stuck.tick_once()
    assert stuck.status == Status.SUCCESS


def test_has_assignment_reads_only_its_robot() -> None:
    has1, has2 = HasAssignment("/robot1", "route"), HasAssignment("/robot2", "route")
    pick = HasAssignment("/robot1", "pick")
    robot_blackboard("/robot1").route = (Pose2D(1.0, 1.0), Pose2D(2.0, 1.0))
    for node in (has1, has2, pick):
        node.tick_once()
    assert (has1.status, has2.status, pick.status) == (Status.SUCCESS, Status.FAILURE, Status.FAILURE)
    robot_blackboard("/robot1").route = ()
    has1.tick_once()
    assert has1.status == Status.FAILURE


def test_recovery_clears_costmaps_runs_wait_backup_spin_and_retry_succeeds_when_unblocked() -> None:
    sim = make_ring_world(NS, Pose2D(1.5, 0.6, 0.0), stuck_time_s=2.0)
    b = sim.backend(NS)
    nav = NavigateToPoseAction(b, Pose2D(7.0, 0.6))
    actions = recovery_actions(b, wait_s=1.0)
    root = RecoveryNode(nav, actions, retries=4)
    obstacle = sim.add_obstacle(*RING_PLUG)
    loop = Loop(sim, root)
    clear_guard, cycle = actions.children
    clear = clear_guard.children[0]  # ClearingActions: the costmaps are cleared first
    wait, backup, spin = cycle.children
    modes: list[str] = []
    loop.on_tick.append(lambda: modes.append(py_trees.blackboard.Blackboard.get(f"{NS}/mode")))

    assert loop.run(60.0, until=lambda: spin.status == Status.RUNNING)
    sim.remove_obstacle(obstacle)
    assert loop.run(60.0, until=lambda: root.status != Status.RUNNING)
    assert root.status == Status.SUCCESS
    assert root.recoveries_started == 3 and root.retry_count == 3
    for leaf in (wait, backup, spin):
        assert (
            isinstance(leaf, GoalAction)
            and leaf.goal_id is not None
            and b.goal_state(leaf.goal_id).status is GoalStatus.SUCCEEDED
        )
    assert nav.goals_sent == 4
    assert isinstance(clear, GoalAction) and clear.goals_sent == 3  # once per recovery
    assert clear.goal_id is not None and b.goal_state(clear.goal_id).status is GoalStatus.SUCCEEDED
    assert "recovery" in modes
    assert pose_of(sim, NS).distance_to(Pose2D(7.0, 0.6)) < 0.3


def test_recovery_node_fails_after_its_retries() -> None:
    sim = make_world({NS: Pose2D(2.0, 3.0)})
    b = sim.backend(NS)
    nav = NavigateToPoseAction(b, Pose2D(*BOX))  # no valid path: fails at once
    root = RecoveryNode(nav, WaitAction(b, 0.5), retries=2)
    loop = Loop(sim, root)
    assert loop.run(10.0, until=lambda: root.status != Status.RUNNING)
    assert root.status == Status.FAILURE
    assert nav.goals_sent == 3 and root.retry_count == 2
    assert "NO_VALID_PATH" in root.feedback_message


def test_round_robin_moves_on_after_failure_and_success() -> None:
    sim = make_world({NS: Pose2D(2.0, 3.0)})
    b = sim.backend(NS)
    bad = NavigateToPoseAction(b, Pose2D(*BOX), name="Bad")
    good = WaitAction(b, 0.2, name="Good")
    rr = RoundRobin("RR", [bad, good])
    loop = Loop(sim, rr)
    assert loop.run(2.0, until=lambda: rr.status == Status.SUCCESS)
    assert (bad.goals_sent, good.goals_sent) == (1, 1)
    loop.run(2.0, until=lambda: rr.status == Status.SUCCESS)  # starts after Good: Bad, then Good
    assert (bad.goals_sent, good.goals_sent) == (2, 2)


def test_restart_on_change_cancels_and_restarts_the_child() -> None:
    sim = make_world({NS: Pose2D(2.0, 3.0)})
    b = sim.backend(NS)
    bb = robot_blackboard(NS)
    bb.charger = Pose2D(6.0, 3.0)
    nav = NavigateToPoseAction(b, read_key(NS, "charger"))
    root = RestartOnChange("OnCharger", nav, read_key(NS, "charger"))
    loop = Loop(sim, root)
    loop.run(1.0)
    first = nav.goal_id
    assert root.status == Status.RUNNING and first is not None
    bb.charger = Pose2D(2.0, 5.0)
    loop.tick()
    assert b.goal_state(first).status is GoalStatus.CANCELED
    assert root.restarts == 1 and nav.goal_id != first
    assert loop.run(30.0, until=lambda: root.status == Status.SUCCESS)
    assert pose_of(sim, NS).distance_to(Pose2D(2.0, 5.0)) < 0.3
