"""Next in line for a busy charger (``TrafficParams.next_in_line``): which busy charger a robot
queues on, and the errand that sends it there instead of to a parking dock first."""

from __future__ import annotations

from fleet.robots import BatteryModel
from fleet.traffic.charger_line import frees_in, next_charger
from fleet.traffic.errands import Errands
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.traffic.purpose import Purpose
from fleet.types import Mode, Pose2D
from tests.fleet.traffic.test_errands import charging, corridor

MODEL = BatteryModel(charge_per_s=0.02, resume=0.95, cruise_mps=0.5)


def test_the_charger_that_frees_soonest_before_arrival_is_chosen() -> None:
    assert abs(frees_in(0.55, MODEL) - 20.0) < 1e-9 and frees_in(0.99, MODEL) == 0.0
    costs = {"a": 20.0, "b": 20.0, "c": 5.0}  # 40 s, 40 s, 10 s of driving at 0.5 m/s
    # a frees in 20 s, b in 10 s (both in time), c in 5 s but the robot is there in 10 s
    assert next_charger(costs, {"a": 0.55, "b": 0.75}, MODEL, margin_s=0.0) == "b"
    assert next_charger(costs, {"a": 0.55, "c": 0.85}, MODEL, margin_s=0.0) == "c"
    assert next_charger(costs, {"c": 0.85}, MODEL, margin_s=6.0) is None  # margin: too late
    assert next_charger(costs, {"a": 0.05}, MODEL, margin_s=0.0) is None  # 45 s > 40 s
    assert next_charger({}, {"a": 0.9}, MODEL) is None  # not within reach


def errands(next_in_line: bool, length_m: float = 10.0) -> tuple[TrafficManager, Errands, dict[str, Purpose]]:
    """Robot C charges on ``cw`` at the west end of a corridor of 4 edges of ``length_m``,
    D on ``ce`` (east end); robot R at ``c1`` must charge; a parking ``bay`` above ``c2``."""
    rm = corridor(length_m)
    tm = TrafficManager(rm, TrafficParams(next_in_line=next_in_line))
    for name, node in {"C": "cw", "D": "ce", "R": "c1"}.items():
        x, y = rm.pos(node)
        tm.add_robot(name, Pose2D(x, y), 0.0)
    purposes: dict[str, Purpose] = {}

    def drive(robot: str, nodes: list[str], purpose: Purpose) -> None:
        tm.set_path(robot, nodes, 0.0)
        purposes[robot] = purpose

    er = Errands(tm, rm, purposes, drive, ["cw", "ce"], ["bay"], park_idle_s=5.0, battery=MODEL)
    requests: list[tuple[float, str]] = []
    er.step("C", charging(rm, "cw", battery=0.5), 0.0, requests)
    er.step("D", charging(rm, "ce", battery=0.1), 0.0, requests)
    er.serve_chargers(requests)  # C and D are sent to the docks they stand on
    assert purposes == {"C": Purpose.CHARGE, "D": Purpose.CHARGE}
    return tm, er, purposes


def test_a_robot_queues_on_the_charger_that_frees_before_it_arrives() -> None:
    tm, er, purposes = errands(next_in_line=True)
    rm = er.roadmap
    requests: list[tuple[float, str]] = []
    # C at 0.9 frees in 2.5 s; R is 10 m (20 s) from cw: it drives straight there
    er.step("C", charging(rm, "cw", battery=0.9), 1.0, requests)
    er.step("R", charging(rm, "c1", battery=0.3), 1.0, requests)
    er.serve_chargers(requests)
    assert purposes["R"] is Purpose.CHARGE and tm.path("R")[-1] == "cw"
    # while C still stands on cw, R keeps its target
    er.step("R", charging(rm, "c1", battery=0.3), 1.5, [])
    assert tm.path("R")[-1] == "cw"
    # C is done (idle): it leaves cw at once for R, without waiting ``park_idle_s``
    x, y = rm.pos("cw")
    done = charging(rm, "cw", battery=0.95)
    done.obs.mode = Mode.IDLE
    er.step("C", done, 2.0, [])
    assert purposes["C"] is Purpose.PARK and tm.path("C")[-1] == "bay"


def test_without_next_in_line_the_robot_waits_on_a_parking_dock() -> None:
    tm, er, purposes = errands(next_in_line=False)
    rm = er.roadmap
    requests: list[tuple[float, str]] = []
    er.step("C", charging(rm, "cw", battery=0.9), 1.0, requests)
    er.step("R", charging(rm, "c1", battery=0.3), 1.0, requests)
    er.serve_chargers(requests)
    assert purposes["R"] is Purpose.CHARGE_WAIT and tm.path("R")[-1] == "bay"


def test_a_robot_does_not_queue_on_a_charger_that_frees_too_late() -> None:
    tm, er, purposes = errands(next_in_line=True, length_m=5.0)  # cw 12 s away, ce 32 s
    rm = er.roadmap
    requests: list[tuple[float, str]] = []
    er.step("C", charging(rm, "cw", battery=0.2), 1.0, requests)  # 37.5 s to go
    er.step("D", charging(rm, "ce", battery=0.1), 1.0, requests)  # 42.5 s to go
    er.step("R", charging(rm, "c1", battery=0.3), 1.0, requests)
    er.serve_chargers(requests)
    assert purposes["R"] is Purpose.CHARGE_WAIT


def test_a_robot_heading_for_a_dock_waits_before_its_junction_while_the_dock_is_held() -> None:
    rm = corridor(2.0)  # w is 4 m from R: within one grant's horizon
    for on in (True, False):
        tm = TrafficManager(rm, TrafficParams(next_in_line=on))
        for name, node in {"C": "cw", "R": "c2"}.items():
            x, y = rm.pos(node)
            tm.add_robot(name, Pose2D(x, y), 0.0)
        tm.set_path("R", ["c2", "c1", "w", "cw"], 0.0)
        tm.cycle(0.1)
        # with the rule, the junction w and the dock cw are one block: R stops at c1, out
        # of C's way off the spur; without it R takes w and stands in C's way out
        assert (tm.holder("w") == "R") is not on
