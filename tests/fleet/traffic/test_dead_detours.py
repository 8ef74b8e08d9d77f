"""A robot on its way to a charger does not drive far round a dead robot, nor round a loop
after stepping aside.

Found by ``fleet chaos`` (docs/faults.md, "Batteries under chaos"): an agent killed and
restarted leaves its robot dead to the traffic manager for a few seconds (tens of simulated
seconds at 10x speed), and every other robot's path through its node was rerouted around it,
however long the way round. A robot at 22 % on its way to a free charger 8 m ahead was sent up
an aisle and along the far row instead (a 36 m detour behind traffic) and ran flat, although the
dead robot's agent was back 17 s later. Now a robot with a detour limit (the charging errand
sets one) waits for the dead robot when the way round is longer than its way plus the limit,
and is rerouted only after ``dead_wait_s`` of waiting (a robot that stays dead). The same
kind of run showed a robot that stepped aside to break a deadlock sent on round a 33 m loop
with the fleet's flow instead of 4 m back: with a limit it comes back the short way."""

from __future__ import annotations

import networkx as nx

from fleet.roadmap.graph import Roadmap
from fleet.traffic.deadlocks import sidestep
from fleet.traffic.errands import CHARGE_DETOUR_M, Errands
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.traffic.purpose import Purpose
from fleet.types import Mode, Pose2D

#: Seconds between two manager cycles in these tests.
STEP_S = 0.5


def row_with_a_long_way_round() -> Roadmap:
    """``a - b - c - dock`` along x, 4 m apart, and a way round ``b`` up an aisle and along a
    far row: ``a - ua - uc - c`` (13 + 8 + 13 m against 8 m); a bay beside ``b``."""
    pos = {
        "a": (0, 0),
        "b": (4, 0),
        "c": (8, 0),
        "dock": (12, 0),
        "ua": (0, 13),
        "uc": (8, 13),
        "bay": (4, 2),
    }
    g = nx.Graph()
    for n, xy in pos.items():
        g.add_node(n, pos=xy)
    g.add_edges_from(
        [("a", "b"), ("b", "c"), ("c", "dock"), ("a", "ua"), ("ua", "uc"), ("uc", "c"), ("b", "bay")]
    )
    return Roadmap.from_graph(g)


def dead_ahead(limit: float | None) -> tuple[TrafficManager, float]:
    """``C`` at ``a`` heading for ``dock``, ``D`` standing on ``b``, declared dead (its agent
    gone); returns the manager and the time."""
    tm = TrafficManager(row_with_a_long_way_round(), TrafficParams(detect_period_s=STEP_S))
    tm.add_robot("D", Pose2D(4, 0), 0.0)
    tm.add_robot("C", Pose2D(0, 0), 0.0)
    tm.set_detour_limit("C", limit)
    tm.set_path("C", ["a", "b", "c", "dock"], 0.0)
    tm.cycle(0.0)
    tm.declare_dead("D", STEP_S)
    tm.cycle(STEP_S)
    return tm, STEP_S


def run_until(tm: TrafficManager, t: float, end: float) -> float:
    while t < end:
        t += STEP_S
        tm.cycle(t)
    return t


def test_without_a_limit_a_robot_is_sent_the_long_way_round_a_dead_robot() -> None:
    tm, _ = dead_ahead(None)
    assert "ua" in tm.path("C") and "b" not in tm.path("C")  # the way it was (any detour)


def test_a_robot_with_a_limit_waits_for_the_dead_robot_and_drives_on_when_it_is_back() -> None:
    tm, t = dead_ahead(CHARGE_DETOUR_M)
    assert tm.path("C") == ["a", "b", "c", "dock"]
    t = run_until(tm, t, 20.0)  # past reroute_after_s (5 s), before dead_wait_s (30 s)
    assert "ua" not in tm.path("C") and tm.grant("C").nodes == ()  # it waits before b
    # the agent is back: D drives off into the bay, C goes on its short way
    tm.declare_alive("D", t)
    tm.set_path("D", ["b", "bay"], t)
    tm.cycle(t)
    tm.update("D", Pose2D(4, 2), t + STEP_S)
    run_until(tm, t, t + 2.0)
    assert tm.path("C")[:2] == ["a", "b"] and "b" in tm.grant("C").nodes


def test_a_robot_that_stays_dead_is_driven_round_after_dead_wait_s() -> None:
    tm, t = dead_ahead(CHARGE_DETOUR_M)
    wait = tm.params.dead_wait_s
    t = run_until(tm, t, wait - 1.0)
    assert "ua" not in tm.path("C")
    run_until(tm, t, wait + 2 * tm.params.reroute_after_s)
    assert "ua" in tm.path("C")  # it does not wait forever


def test_the_charging_errand_sets_the_limit_and_the_end_of_the_charge_clears_it() -> None:
    rm = row_with_a_long_way_round()
    tm = TrafficManager(rm, TrafficParams(detect_period_s=STEP_S))
    tm.add_robot("C", Pose2D(0, 0), 0.0)
    purposes: dict[str, Purpose] = {}

    def drive(robot: str, nodes: list[str], purpose: Purpose) -> None:
        tm.set_path(robot, nodes, 0.0)
        purposes[robot] = purpose

    er = Errands(tm, rm, purposes, drive, ["dock"], ["bay"], park_idle_s=5.0)

    class View:
        def __init__(self, mode: str) -> None:
            self.alive, self.assignment = True, None
            self.obs = type("Obs", (), {"mode": mode, "battery": 0.3, "pose": Pose2D(0, 0)})()

    requests: list[tuple[float, str]] = []
    er.step("C", View(Mode.CHARGING), 0.0, requests)
    er.serve_chargers(requests)
    assert purposes["C"] is Purpose.CHARGE
    assert tm.detour_limit("C") == CHARGE_DETOUR_M
    er.step("C", View(Mode.IDLE), 1.0, [])  # charged: simply idle now
    assert tm.detour_limit("C") is None


def test_a_robot_with_a_limit_steps_aside_and_comes_back_the_short_way() -> None:
    """A deadlock is broken by a robot stepping aside; its way on from the side node was
    planned with the fleet's flow, round a loop (21 m here, 33 m in the chaos run) rather than
    back 3 m against the flow. A robot with a detour limit comes back the short way."""
    pos = {"q": (4, 0), "goal": (8, 0), "side": (4, -3), "f1": (4, -10), "f2": (8, -10)}
    g = nx.Graph()
    for n, xy in pos.items():
        g.add_node(n, pos=xy)
    loop = [("goal", "q"), ("q", "side"), ("side", "f1"), ("f1", "f2"), ("f2", "goal")]
    g.add_edges_from(loop)
    for limit, way_on in ((None, ["side", "f1", "f2", "goal"]), (CHARGE_DETOUR_M, ["side", "q", "goal"])):
        tm = TrafficManager(Roadmap.from_graph(g), TrafficParams(detect_period_s=STEP_S))
        tm.set_flow(loop)  # the patrol direction: q -> goal is against it
        tm.add_robot("O", Pose2D(8, 0), 0.0)  # on the goal: R must make way
        tm.add_robot("R", Pose2D(4, 0), 0.0)
        tm.set_detour_limit("R", limit)
        tm.set_path("R", ["q", "goal"], 0.0)
        tm.cycle(0.0)
        assert sidestep(tm._st, tm._st.get("R"), {"O"}, 0.0, back=True)
        assert tm.path("R") == ["q", *way_on], limit
