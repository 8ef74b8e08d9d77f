"""The battery guard's trigger of a traffic-managed robot: measured to the charger it will be
sent to (a free one near it), not only to the charger the coordinator named near its work."""

from __future__ import annotations

import pytest
from nodes_world import CHARGER, make_world
from py_trees.common import Status

from fleet.clock import SimClock
from fleet.robots import BatteryModel
from fleet.runtime.agent import RobotAgent
from fleet.traffic.purpose import CHARGE_REACH_M
from fleet.types import Pose2D
from fleet.wake import Wake
from nodes.blackboard import robot_blackboard
from nodes.conditions import BatteryLow
from nodes.trees import ChargeThreshold

NS = "/robot1"
BATTERY = BatteryModel()
#: A charger named near the robot's new work, 150 m across the floor from where it stands.
FAR = Pose2D(150.0, 3.0, 0.0)


def _guard(sim_battery: float, sites: tuple[Pose2D, ...]) -> tuple[BatteryLow, ChargeThreshold]:
    sim = make_world({NS: (Pose2D(2.0, 3.0), sim_battery)})
    bb = robot_blackboard(NS, name="agent")
    bb.charger = FAR
    bb.charger_sites = sites
    threshold = ChargeThreshold(NS, sim.backend(NS), BATTERY)
    return BatteryLow(sim.backend(NS), BATTERY.low, BATTERY.resume, threshold=threshold), threshold


def test_a_charged_robot_far_from_its_named_charger_goes_back_to_work() -> None:
    """At 90 % a robot 150 m from its named charger must, measured to that charger alone,
    charge at once (the threshold is at ``resume``: it would charge, take work, charge again
    for as long as it stays far). With the charger sites it measures to the charger 3 m away
    plus the policy's reach, and works on."""
    named_only, t0 = _guard(0.9, ())
    named_only.tick_once()
    assert named_only.status == Status.SUCCESS  # the trip to the named charger: ~150 m
    assert t0() == pytest.approx(BATTERY.charge_threshold(148.0))
    assert t0() > BATTERY.resume

    near, t1 = _guard(0.9, (FAR, CHARGER))
    near.tick_once()
    assert near.status == Status.FAILURE
    assert t1() == pytest.approx(BATTERY.charge_threshold(3.0 + CHARGE_REACH_M))


@pytest.mark.parametrize("named", [CHARGER, Pose2D(60.0, 3.0, 0.0)])
def test_a_robot_that_can_work_measures_to_its_named_charger(named: Pose2D) -> None:
    """Nothing changes while the named charger's threshold is below ``resume``: a robot
    3 m or 58 m from its named charger keeps its threshold, though another is nearer."""
    _, t = _guard(0.9, (Pose2D(3.0, 3.0, 0.0), CHARGER, named))
    robot_blackboard(NS, name="agent").charger = named
    d = abs(named.x - 2.0) + abs(named.y - 3.0)
    assert BATTERY.charge_threshold(d) < BATTERY.resume
    assert t() == pytest.approx(BATTERY.charge_threshold(d))


@pytest.mark.parametrize("sites", [(), (FAR, CHARGER), (FAR, CHARGER, Pose2D(30.0, 5.0, 0.0))])
def test_the_declared_line_is_the_threshold_here_and_never_below_it(sites: tuple[Pose2D, ...]) -> None:
    """The event-driven scheduler ticks the guard when the battery falls below the declared
    line: at the robot's pose it is the threshold itself, and wherever the robot drives it is
    never below the threshold there, so the guard never ticks too late. A robot measuring to
    a nearest site (far from its named charger) is ticked every period."""
    _, t = _guard(0.9, sites)
    far = Wake()
    t.declare(far, BATTERY.resume)
    assert far.always == bool(sites)
    robot_blackboard(NS, name="agent").charger = Pose2D(40.0, 3.0, 0.0)  # a line again
    wake = Wake()
    t.declare(wake, BATTERY.resume)
    assert wake.line is not None
    low, cap, a, b, cx, cy = wake.line

    def line(x: float, y: float) -> float:
        return min(cap, max(low, a + b * (abs(x - cx) + abs(y - cy))))

    assert line(2.0, 3.0) == pytest.approx(min(BATTERY.resume, t()))
    for x, y in [(10.0, 3.0), (29.0, 5.0), (80.0, 1.0), (149.0, 3.0), (2.0, 40.0), (150.0, 90.0)]:
        measured = t._measure(Pose2D(x, y))  # noqa: SLF001 - the threshold at another pose
        assert measured is not None
        assert line(x, y) >= min(cap, BATTERY.charge_threshold(measured[0])) - 1e-12


def test_the_agent_writes_the_sites_under_traffic_management_only() -> None:
    sim = make_world({NS: Pose2D(2.0, 3.0)})
    chargers = (CHARGER, FAR)
    for traffic, near, want in [(True, True, chargers), (True, False, ()), (False, True, ())]:
        agent = RobotAgent(
            NS, sim.backend(NS), SimClock(), None, traffic=traffic, chargers=chargers, near_chargers=near
        )
        assert agent.bb.charger_sites == want
