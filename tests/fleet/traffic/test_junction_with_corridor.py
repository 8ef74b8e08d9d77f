"""A robot about to drive into an aisle takes the aisle-end junction only together with the
aisle (``TrafficParams.junction_with_corridor``): otherwise it may hold that junction while
a robot leaving the aisle needs it, each waiting for the other (the remaining deadlock
episodes of the 100-robot load test, ``docs/traffic.md``, "Junction with the corridor")."""

from __future__ import annotations

import networkx as nx
from node_hops import hop_to_goals

from fleet.roadmap.graph import Roadmap
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.types import Pose2D

# one aisle s - x1 .. x7 - n (cells 1.5 m apart), junctions at both ends with a corridor
# west and east of each
AISLE = [f"x{i}" for i in range(1, 8)]
NODES = {"s": (0.0, 0.0), "n": (0.0, 12.0), "nw": (-2.0, 12.0), "ne": (2.0, 12.0)}
NODES |= {"sw": (-2.0, 0.0), "se": (2.0, 0.0)}
NODES |= {x: (0.0, 1.5 * (i + 1)) for i, x in enumerate(AISLE)}
GOALS = {"A": "ne", "B": "se"}


def _world(rule: bool) -> TrafficManager:
    g: nx.Graph[str] = nx.Graph()
    for name, xy in NODES.items():
        g.add_node(name, pos=xy)
    chain = ["s", *AISLE, "n"]
    g.add_edges_from(zip(chain, chain[1:], strict=False))
    g.add_edges_from([("n", "nw"), ("n", "ne"), ("s", "sw"), ("s", "se")])
    params = TrafficParams(
        deadlock_detect_s=1.0, detect_period_s=0.1, junction_with_corridor=3 if rule else 0
    )
    tm = TrafficManager(Roadmap.from_graph(g), params)
    # A drives up the aisle towards n; nobody comes the other way yet, so its grant stops
    # short of the junction n (horizon_m ahead)
    tm.add_robot("A", Pose2D(*NODES["x1"], 0.0), 0.0)
    tm.add_robot("B", Pose2D(*NODES["nw"], 0.0), 0.0)
    tm.set_path("A", [*AISLE, "n", "ne"], 0.0)
    tm.cycle(0.0)
    assert "n" not in tm.grant("A").nodes
    # then B, beside n, is sent down the same aisle the other way
    tm.set_path("B", ["nw", "n", *reversed(AISLE), "s", "se"], 0.0)
    return tm


def _drive(tm: TrafficManager, until_s: float) -> float:
    """:func:`hop_to_goals`: the time both arrived (``until_s`` if not)."""
    return hop_to_goals(tm, GOALS, until_s)


def test_a_robot_holding_the_aisle_end_to_enter_meets_one_leaving_the_aisle() -> None:
    tm = _world(rule=False)
    tm.cycle(0.1)
    assert tm.table.holder("n") == "B"  # B took the junction A drives out through
    _drive(tm, 60.0)
    assert tm.metrics.deadlocks_detected >= 1


def test_the_junction_comes_with_the_aisle_and_nobody_waits_in_a_cycle() -> None:
    tm = _world(rule=True)
    tm.cycle(0.1)
    assert tm.table.holder("n") != "B"  # the aisle is A's: B waits off the junction
    t = _drive(tm, 60.0)
    assert t < 60.0, {n: (tm.path(n), tm.blockers(n)) for n in GOALS}
    assert tm.metrics.deadlocks_detected == 0
