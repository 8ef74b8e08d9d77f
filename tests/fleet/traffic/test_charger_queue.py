"""The charger queue: a free charger goes to the robot for which it matters (a robot that
cannot afford to wait first, then the nearest), a robot queues for a charger that frees
before it arrives and the charged robot leaves it at once, an idle robot on a charger gives
it up to a robot that needs it, and the bounded charger search gives the answers of a search
over the whole roadmap."""

from __future__ import annotations

import math
import random

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.roadmap.graph import Roadmap
from fleet.robots import BatteryModel
from fleet.traffic.charger_queue import ChargeNeed, assign_chargers, spare, urgent_below
from fleet.traffic.errands import Errands
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.traffic.purpose import Purpose
from fleet.traffic.roads import RoadIndex
from fleet.types import Mode, Pose2D

MODEL = BatteryModel()


def test_the_nearest_robot_takes_a_free_charger_before_a_far_one_that_can_wait() -> None:
    # the far robot has the lower battery, but 17 m cost it far less than it has to spare
    far, near = ChargeNeed("far", 0.30, {"c": 17.0}), ChargeNeed("near", 0.35, {"c": 1.0})
    assert spare(MODEL, 0.30, 17.0) > urgent_below(MODEL)
    assert assign_chargers([far, near], MODEL) == {"near": "c"}


def test_a_robot_that_cannot_wait_goes_first_even_when_farther() -> None:
    far, near = ChargeNeed("far", 0.14, {"c": 17.0}), ChargeNeed("near", 0.35, {"c": 1.0})
    assert spare(MODEL, 0.14, 17.0) < urgent_below(MODEL)
    assert assign_chargers([near, far], MODEL) == {"far": "c"}


def test_robots_and_chargers_pair_nearest_first_and_each_charger_goes_once() -> None:
    needs = [
        ChargeNeed("a", 0.4, {"c1": 2.0, "c2": 9.0}),
        ChargeNeed("b", 0.4, {"c1": 3.0, "c2": 4.0}),
        ChargeNeed("c", 0.4, {"c1": 1.0}),
        ChargeNeed("d", 0.4, {}),  # no charger within reach: none
    ]
    got = assign_chargers(needs, MODEL)
    assert got == {"c": "c1", "b": "c2"}
    assert assign_chargers(list(reversed(needs)), MODEL) == got  # order does not matter
    tie = [ChargeNeed("y", 0.4, {"c": 5.0}), ChargeNeed("x", 0.4, {"c": 5.0})]
    assert assign_chargers(tie, MODEL) == {"x": "c"}  # ties: the least name


# -- the queue on a roadmap -------------------------------------------------------------


class Obs:
    def __init__(self, mode: str, battery: float, pose: Pose2D) -> None:
        self.mode, self.battery, self.pose = mode, battery, pose


class View:
    def __init__(self, mode: str, battery: float, pose: Pose2D) -> None:
        self.alive, self.assignment = True, None
        self.obs = Obs(mode, battery, pose)


def corridor() -> Roadmap:
    """w - m - e along x (10 m apart), a charger dock under w (``cw``) and under e (``ce``),
    parking docks above w (``pw``) and above e (``pe``)."""
    pos = {"w": (0, 0), "m": (10, 0), "e": (20, 0), "cw": (0, -1), "ce": (20, -1), "pw": (0, 1)}
    pos["pe"] = (20, 1)
    g = nx.Graph()
    for n, xy in pos.items():
        g.add_node(n, pos=xy)
    g.add_edges_from([("w", "m"), ("m", "e"), ("w", "cw"), ("e", "ce"), ("w", "pw"), ("e", "pe")])
    return Roadmap.from_graph(g)


def errands_on(rm: Roadmap, robots: dict[str, str]) -> tuple[TrafficManager, Errands, dict[str, Purpose]]:
    tm = TrafficManager(rm, TrafficParams(detect_period_s=0.5))
    for name, node in robots.items():
        x, y = rm.pos(node)
        tm.add_robot(name, Pose2D(x, y), 0.0)
    purposes: dict[str, Purpose] = {}

    def drive(robot: str, nodes: list[str], purpose: Purpose) -> None:
        tm.set_path(robot, nodes, 0.0)
        purposes[robot] = purpose

    er = Errands(tm, rm, purposes, drive, ["cw", "ce"], ["pw", "pe"], park_idle_s=5.0, battery=MODEL)
    return tm, er, purposes


def view(rm: Roadmap, node: str, mode: str, battery: float) -> View:
    x, y = rm.pos(node)
    return View(mode, battery, Pose2D(x, y))


def test_a_robot_queues_for_a_charger_that_frees_before_it_arrives_and_the_charged_one_leaves() -> None:
    rm = corridor()
    # Z charges on cw and is nearly full, Y on ce far from full; R at m needs a charger
    tm, er, purposes = errands_on(rm, {"Z": "cw", "Y": "ce", "R": "m"})
    for robot, dock in (("Z", "cw"), ("Y", "ce")):
        purposes[robot] = Purpose.CHARGE
        er._target[robot] = dock
    requests: list[tuple[float, str]] = []
    er.step("Z", view(rm, "cw", Mode.CHARGING, 0.9), 0.0, requests)  # frees in 2.5 s
    er.step("Y", view(rm, "ce", Mode.CHARGING, 0.1), 0.0, requests)  # in 42.5 s
    er.step("R", view(rm, "m", Mode.CHARGING, 0.3), 0.0, requests)
    er.serve_chargers(requests)
    # cw frees long before R (11 m away) gets there: R drives to it instead of waiting
    assert purposes["R"] is Purpose.CHARGE and tm.path("R")[-1] == "cw"
    er.step("R", view(rm, "m", Mode.CHARGING, 0.3), 0.5, [])
    assert tm.path("R")[-1] == "cw"  # Z still charges there: R stays next in line
    # Z is charged and has no work: it leaves the charger at once (not park_idle_s later)
    er.step("Z", view(rm, "cw", Mode.IDLE, MODEL.resume), 1.0, [])
    assert purposes["Z"] is Purpose.PARK and tm.path("Z")[-1] == "pw"
    # a robot charged with nobody queued for its charger stays (it charges on, nobody waits)
    er.step("Y", view(rm, "ce", Mode.IDLE, MODEL.resume), 1.0, [])
    assert tm.path("Y")[-1] == "ce"


def test_an_idle_robot_on_a_charger_gives_it_to_a_robot_that_needs_it() -> None:
    rm = corridor()
    # Z idles on cw, topping up below resume; ce is free but 20 m farther for R at w
    tm, er, purposes = errands_on(rm, {"Z": "cw", "R": "w"})
    purposes["Z"] = Purpose.PARK
    er._target["Z"] = "cw"
    requests: list[tuple[float, str]] = []
    er.step("Z", view(rm, "cw", Mode.IDLE, 0.5), 0.0, requests)
    er.step("R", view(rm, "w", Mode.CHARGING, 0.3), 0.0, requests)
    er.serve_chargers(requests)
    assert purposes["R"] is Purpose.CHARGE and tm.path("R")[-1] == "cw"
    assert purposes["Z"] is Purpose.PARK and tm.path("Z")[-1] == "pw"
    # R keeps its target while Z, leaving, still stands on the dock
    er.step("R", view(rm, "w", Mode.CHARGING, 0.3), 0.5, [])
    assert tm.path("R")[-1] == "cw" and purposes["R"] is Purpose.CHARGE


def test_a_robot_on_its_way_to_charge_keeps_the_charger_it_was_given() -> None:
    rm = corridor()
    tm, er, purposes = errands_on(rm, {"A": "m", "B": "e"})
    requests: list[tuple[float, str]] = []
    er.step("A", view(rm, "m", Mode.CHARGING, 0.3), 0.0, requests)
    er.step("B", view(rm, "e", Mode.CHARGING, 0.3), 0.0, requests)
    er.serve_chargers(requests)
    assert tm.path("B")[-1] == "ce" and tm.path("A")[-1] == "cw"
    # a third robot asking later finds both reserved: it waits on a parking dock
    tm.add_robot("C", Pose2D(0.0, 1.0), 0.5)
    requests = []
    er.step("C", view(rm, "pw", Mode.CHARGING, 0.3), 0.5, requests)
    er.serve_chargers(requests)
    assert purposes["C"] is Purpose.CHARGE_WAIT and tm.path("A")[-1] == "cw"


# -- the bounded search -----------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), reach=st.sampled_from([0.0, 3.0, 10.0, math.inf]))
def test_the_bounded_search_gives_the_whole_roadmaps_costs_within_reach(seed: int, reach: float) -> None:
    rng = random.Random(seed)
    g = nx.connected_watts_strogatz_graph(30, 4, 0.3, seed=seed)
    h: nx.Graph[str] = nx.Graph()
    for n in g.nodes:
        h.add_node(f"n{n}", pos=(rng.uniform(0, 20), rng.uniform(0, 20)))
    for a, b in g.edges:
        h.add_edge(f"n{a}", f"n{b}", length=rng.choice([1.0, 2.0, 2.5, 4.0]))
    roads = RoadIndex(h)
    roads.set_flow([(f"n{a}", f"n{b}") for a, b in g.edges if rng.random() < 0.5], penalty=4.0)
    here = f"n{rng.randrange(30)}"
    targets = {f"n{i}" for i in rng.sample(range(30), 5)}
    whole = {t: c for t, c in roads.costs_from(here).items() if t in targets}
    nearest = min(whole.values())
    want = {t: c for t, c in whole.items() if c <= nearest + reach}
    assert roads.costs_near(here, targets, reach) == want
