"""Charging errands and the deadlocks around them: a robot nudged off its way to a charger is
sent on again, a robot blocked on its errand takes a free charger it can reach without passing
its blockers, a free charger far beyond a busy near one is not taken, and a starving robot's
claim on what the robot ahead needs is dropped to break the cycle it makes."""

from __future__ import annotations

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.roadmap.graph import Roadmap
from fleet.traffic.deadlocks import resolve
from fleet.traffic.errands import CHARGE_REACH_M, RETARGET_AFTER_S, Errands
from fleet.traffic.grants import claim
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.traffic.purpose import Purpose
from fleet.types import Mode, Pose2D


class Obs:
    def __init__(self, mode: str, battery: float, pose: Pose2D) -> None:
        self.mode, self.battery, self.pose = mode, battery, pose


class View:
    def __init__(self, mode: str, battery: float, pose: Pose2D) -> None:
        self.alive, self.assignment = True, None
        self.obs = Obs(mode, battery, pose)


def corridor(length_m: float = 10.0) -> Roadmap:
    """w - c1 - c2 - c3 - e along x (``length_m`` between nodes) with a charger dock below
    each end (``cw`` under w, ``ce`` under e), a bay above c2 and a spot ``qw`` above w."""
    d = length_m
    pos = {"w": (0, 0), "c1": (d, 0), "c2": (2 * d, 0), "c3": (3 * d, 0), "e": (4 * d, 0)}
    pos |= {"cw": (0, -1), "ce": (4 * d, -1), "bay": (2 * d, 2), "qw": (0, 2)}
    g = nx.Graph()
    for n, xy in pos.items():
        g.add_node(n, pos=xy)
    g.add_edges_from([("w", "c1"), ("c1", "c2"), ("c2", "c3"), ("c3", "e"), ("w", "cw"), ("e", "ce")])
    g.add_edges_from([("c2", "bay"), ("w", "qw")])
    return Roadmap.from_graph(g)


def errands_on(
    rm: Roadmap, robots: dict[str, str], **params: float | bool
) -> tuple[TrafficManager, Errands, dict[str, Purpose]]:
    tm = TrafficManager(rm, TrafficParams(detect_period_s=0.5, **params))  # type: ignore[arg-type]
    for name, node in robots.items():
        x, y = rm.pos(node)
        tm.add_robot(name, Pose2D(x, y), 0.0)
    purposes: dict[str, Purpose] = {}

    def drive(robot: str, nodes: list[str], purpose: Purpose) -> None:
        tm.set_path(robot, nodes, 0.0)
        purposes[robot] = purpose

    return tm, Errands(tm, rm, purposes, drive, ["cw", "ce"], ["bay"], park_idle_s=5.0), purposes


def charging(rm: Roadmap, node: str, battery: float = 0.3) -> View:
    x, y = rm.pos(node)
    return View(Mode.CHARGING, battery, Pose2D(x, y))


def test_a_robot_nudged_off_its_way_to_a_charger_is_sent_on_again() -> None:
    rm = corridor()
    tm, er, purposes = errands_on(rm, {"R": "c2"})
    requests: list[tuple[float, str]] = []
    er.step("R", charging(rm, "c2"), 0.0, requests)
    er.serve_chargers(requests)
    assert purposes["R"] is Purpose.CHARGE and tm.path("R")[-1] in ("cw", "ce")
    target = tm.path("R")[-1]
    tm.set_path("R", ["c2", "bay"], 1.0)  # what a nudge to make room does: it ends elsewhere
    er.step("R", charging(rm, "c2"), 1.0, [])
    assert tm.path("R")[-1] == target and purposes["R"] is Purpose.CHARGE


def test_a_free_charger_far_beyond_the_busy_near_one_is_not_taken() -> None:
    rm = corridor(length_m=CHARGE_REACH_M)  # ce is 4 * reach from cw
    tm, er, purposes = errands_on(rm, {"R": "w", "Z": "cw"})  # Z stands on the near charger
    requests: list[tuple[float, str]] = []
    er.step("R", charging(rm, "w"), 0.0, requests)
    er.serve_chargers(requests)
    # it waits for cw (off the aisle at the bay only if that is nearer than the far charger)
    assert purposes["R"] is Purpose.CHARGE_WAIT and tm.path("R")[-1] == "bay"
    rm2 = corridor(length_m=CHARGE_REACH_M / 8)  # now ce is within reach: it goes there
    tm2, er2, purposes2 = errands_on(rm2, {"R": "w", "Z": "cw"})
    requests = []
    er2.step("R", charging(rm2, "w"), 0.0, requests)
    er2.serve_chargers(requests)
    assert purposes2["R"] is Purpose.CHARGE and tm2.path("R")[-1] == "ce"


def test_a_robot_blocked_on_its_way_to_a_charger_takes_one_it_reaches_without_passing() -> None:
    rm = corridor()
    # Q (lower battery, beside w) is sent to cw, so R (at c1) is sent to ce, past c2
    tm, er, purposes = errands_on(rm, {"R": "c1", "B": "c2", "Q": "qw"})
    requests: list[tuple[float, str]] = []
    er.step("Q", charging(rm, "qw", battery=0.1), 0.0, requests)
    er.step("R", charging(rm, "c1"), 0.0, requests)
    er.serve_chargers(requests)
    assert tm.path("Q")[-1] == "cw" and tm.path("R")[-1] == "ce"
    er.forget("Q")  # Q got work instead: cw is free again
    tm.clear_path("Q", 0.5)
    tm.set_path("B", ["c2", "c1", "w"], 0.5)  # B heads west through R: head-on
    tm.cycle(1.0)
    assert "R" in tm.waiting() and tm.blockers("R") == {"B"}
    t = 1.0
    while t <= 1.0 + RETARGET_AFTER_S:
        er.step("R", charging(rm, "c1"), t, [])
        t += 0.5
    assert tm.path("R") == ["c1", "w", "cw"] and purposes["R"] is Purpose.CHARGE


def test_a_starving_robots_claim_on_what_the_robot_ahead_needs_is_dropped() -> None:
    rm = corridor()
    tm, _, _ = errands_on(rm, {"L": "c2", "F": "c1"})
    st = tm._st
    lead, follower = st.robots["L"], st.robots["F"]
    # F (behind L) starved and claimed c3, which L needs next; L waits on F's claim, F on L
    claim(st, follower, ["c3"])
    assert tm.claimant("c3") == "F"
    lead.blocked_on, lead.blockers = {"c3"}, {"F"}
    follower.blocked_on, follower.blockers = {"c2"}, {"L"}
    assert resolve(st, {"L", "F"}, 10.0)
    assert tm.claimant("c3") is None and "L" in follower.yield_to
    claim(st, follower, ["c2", "c3"])  # starving again: it does not claim what it yields
    assert tm.claimant("c3") is None


def _sent_to_ce_with_cw_free(**params: float | bool) -> tuple[TrafficManager, Errands, dict[str, Purpose]]:
    """R (at c1) is sent to the far charger ``ce`` because Q (lower battery) took ``cw``;
    then Q gets work and ``cw`` is free again."""
    rm = corridor()
    tm, er, purposes = errands_on(rm, {"R": "c1", "Q": "qw"}, **params)
    requests: list[tuple[float, str]] = []
    er.step("Q", charging(rm, "qw", battery=0.1), 0.0, requests)
    er.step("R", charging(rm, "c1"), 0.0, requests)
    er.serve_chargers(requests)
    assert tm.path("Q")[-1] == "cw" and tm.path("R")[-1] == "ce"
    er.forget("Q")
    tm.clear_path("Q", 0.5)
    return tm, er, purposes


def _drive(tm: TrafficManager, robot: str, nodes: list[str], t: float) -> float:
    """Drive ``robot`` node by node along ``nodes`` (each granted first); the time after."""
    for n in nodes:
        for _ in range(20):
            tm.cycle(t)
            t += 0.5
            if n in tm.grant(robot).nodes or tm.path(robot)[:1] == [n]:
                break
        x, y = tm.node_pos(n)
        tm.update(robot, Pose2D(x, y), t)
        tm.cycle(t)
        t += 0.5
    return t


def test_a_robot_stepped_aside_onto_a_free_charger_charges_there() -> None:
    tm, er, purposes = _sent_to_ce_with_cw_free(charge_where_stepped=True)
    rm = er.roadmap
    tm.set_path("R", ["c1", "w", "cw"], 1.0)  # what a side step does: it ends on another dock
    t = _drive(tm, "R", ["w", "cw"], 1.0)
    assert tm.path("R")[0] == "cw"
    er.step("R", charging(rm, "cw"), t, [])
    # it stays on cw and charges there; ce is free for the next robot that needs a charger
    assert tm.path("R") == ["cw"] and purposes["R"] is Purpose.CHARGE
    assert "ce" not in er._target.values()


def test_without_the_rule_a_stepped_aside_robot_drives_on_to_its_charger() -> None:
    tm, er, purposes = _sent_to_ce_with_cw_free()  # the default
    rm = er.roadmap
    tm.set_path("R", ["c1", "w", "cw"], 1.0)
    t = _drive(tm, "R", ["w", "cw"], 1.0)
    er.step("R", charging(rm, "cw"), t, [])
    assert tm.path("R")[-1] == "ce" and purposes["R"] is Purpose.CHARGE


def test_a_blocked_robot_takes_no_dock_beyond_the_retarget_reach() -> None:
    rm = corridor()
    tm, er, purposes = errands_on(rm, {"R": "c1", "B": "c2", "Q": "qw"}, retarget_reach_m=5.0)
    requests: list[tuple[float, str]] = []
    er.step("Q", charging(rm, "qw", battery=0.1), 0.0, requests)
    er.step("R", charging(rm, "c1"), 0.0, requests)
    er.serve_chargers(requests)
    er.forget("Q")
    tm.clear_path("Q", 0.5)
    tm.set_path("B", ["c2", "c1", "w"], 0.5)  # head-on, as in the test above
    tm.cycle(1.0)
    assert tm.blockers("R") == {"B"}
    t = 1.0
    while t <= 1.0 + RETARGET_AFTER_S:
        er.step("R", charging(rm, "c1"), t, [])
        t += 0.5
    # cw is 11 m away, beyond the 5 m reach: R keeps its way to ce and waits
    assert tm.path("R")[-1] == "ce" and purposes["R"] is Purpose.CHARGE


def _head_on_at_c2(**params: float | bool) -> tuple[TrafficManager, Errands, dict[str, Purpose]]:
    """R (at c2) heads west for ``cw``; B (at c1) drives east into it: head-on. ``ce`` (21 m
    east, as far as ``cw``) is free; R waits on B for :data:`RETARGET_AFTER_S`."""
    rm = corridor()
    tm, er, purposes = errands_on(rm, {"R": "c2", "B": "c1"}, retarget_reach_m=30.0, **params)
    er._target["R"] = "cw"
    purposes["R"] = Purpose.CHARGE
    tm.set_path("R", ["c2", "c1", "w", "cw"], 0.0)
    tm.set_path("B", ["c1", "c2", "c3"], 0.0)
    tm.cycle(1.0)
    assert tm.blockers("R") == {"B"}
    t = 1.0
    while t <= 1.0 + RETARGET_AFTER_S:
        er.step("R", charging(rm, "c2"), t, [])
        t += 0.5
    return tm, er, purposes


def test_a_blocked_robot_takes_another_dock_only_by_a_shorter_way_when_asked() -> None:
    tm, _, _ = _head_on_at_c2()  # the default: the nearest free dock it reaches, round B
    assert tm.path("R")[-1] == "ce"
    tm, _, purposes = _head_on_at_c2(retarget_shorter=True)
    # ce is no nearer than cw: R keeps its charger and waits (B is resolved by the manager)
    assert tm.path("R")[-1] == "cw" and purposes["R"] is Purpose.CHARGE


def test_the_robot_with_the_least_energy_margin_gets_the_free_charger_first() -> None:
    from fleet.robots import BatteryModel

    rm = corridor()

    def first_served(by_margin: bool) -> str:
        tm = TrafficManager(rm, TrafficParams(charge_margin_priority=by_margin))
        for name, node in {"N": "w", "F": "c3", "Z": "ce"}.items():
            tm.add_robot(name, Pose2D(*rm.pos(node)), 0.0)
        purposes: dict[str, Purpose] = {}

        def drive(robot: str, nodes: list[str], purpose: Purpose) -> None:
            tm.set_path(robot, nodes, 0.0)
            purposes[robot] = purpose

        er = Errands(tm, rm, purposes, drive, ["cw", "ce"], ["bay"], 5.0, BatteryModel())
        requests: list[tuple[float, str]] = []
        # Z stands on ce: cw is the only free charger. N (20 %) stands beside it; F (22 %)
        # is 31 m from it, about 18 % of battery away: F has the least margin
        er.step("N", charging(rm, "w", battery=0.20), 0.0, requests)
        er.step("F", charging(rm, "c3", battery=0.22), 0.0, requests)
        er.serve_chargers(requests)
        assert purposes["N"] is not purposes["F"]
        return "N" if purposes["N"] is Purpose.CHARGE else "F"

    assert first_served(by_margin=False) == "N"  # lowest battery first
    assert first_served(by_margin=True) == "F"


@settings(max_examples=60, deadline=None)
@given(
    targets=st.dictionaries(st.sampled_from([f"r{i}" for i in range(6)]), st.sampled_from(list("abcdef"))),
    holds=st.dictionaries(st.sampled_from(list("abcdefg")), st.sampled_from([f"r{i}" for i in range(6)])),
    robot=st.sampled_from([f"r{i}" for i in range(7)]),
)
def test_the_charger_queues_dock_scans_give_what_the_plain_scans_gave(
    targets: dict[str, str], holds: dict[str, str], robot: str
) -> None:
    """The free docks of a queued robot (``Errands._taken_by_others`` and
    ``TrafficManager.free_docks``, set operations and one pass over the table) are the plain
    scans' answer: docks nobody else holds or heads for, in the docks' order."""
    from fleet.traffic.reservations import ReservationTable

    e = Errands.__new__(Errands)
    e._target = dict(targets)
    taken = {n for r, n in targets.items() if r != robot}
    assert e._taken_by_others(robot) == taken
    table = ReservationTable()
    for res, who in holds.items():
        table.try_acquire(who, [res])
    docks = list("gfedcba")
    plain = [d for d in docks if table.holder(d) in (None, robot) and d not in taken]
    assert table.free_for(robot, docks, taken) == plain
    assert table.free_for(None, docks, set(targets.values())) == [
        d for d in docks if table.holder(d) is None and d not in set(targets.values())
    ]
