"""Where a deadlocked robot steps aside (``fleet.traffic.deadlocks``): never onto the way of a
robot about to come through, where another free node is near."""

from __future__ import annotations

import networkx as nx

from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.types import Pose2D


def test_a_robot_steps_aside_off_the_way_a_third_robot_is_about_to_take() -> None:
    """A and B meet head-on at the junction b. A steps aside; of the two free bays beside b,
    s1 lies on the way robot C is about to drive (t -> s1 -> b): A takes s2. Before, it
    took the first free bay (s1) and met C head-on there; on the 100-robot load test such side
    steps into an aisle or onto a corridor node made most of the deadlock episodes."""
    g: nx.Graph[str] = nx.Graph()
    xy = {"a": (0, 0), "b": (2, 0), "c": (4, 0), "s1": (2, 2), "s2": (2, -2), "t": (2, 4)}
    xy |= {"t2": (2, 6), "u": (4, 4)}
    for n, p in xy.items():
        g.add_node(n, pos=p)
    g.add_edges_from([("a", "b"), ("b", "c"), ("b", "s1"), ("b", "s2"), ("s1", "t"), ("t", "t2"), ("t", "u")])
    params = TrafficParams(deadlock_detect_s=1.0, detect_period_s=0.1, horizon_m=1.5)
    tm = TrafficManager(g, params)
    tm.add_robot("A", Pose2D(0, 0), 0.0)
    tm.add_robot("B", Pose2D(4, 0), 0.0)
    tm.add_robot("C", Pose2D(2, 6), 0.0)
    tm.set_path("A", ["a", "b", "c"], 0.0)
    tm.set_path("B", ["c", "b", "a"], 0.0)
    tm.set_path("C", ["t2", "t", "s1", "b", "a"], 0.0)  # about to come down through s1
    tm.cycle(0.0)
    assert tm.holder("b") == "A" and tm.holder("s1") is None
    tm.update("A", Pose2D(2, 0), 0.5)  # A reaches the junction
    t = 0.5
    while tm.metrics.sidesteps == 0 and t < 10.0:
        t += 0.1
        tm.cycle(t)
    assert tm.metrics.sidesteps == 1, tm.metrics.events
    assert "s2" in tm.grant("A").nodes and "s1" not in tm.path("A")
    tm.check()


def test_a_robot_lets_another_out_of_a_corridor_before_taking_its_mouth() -> None:
    """a - b - c - d with a bay at b; A goes a -> d, B comes out of the corridor c -> b -> a.
    A does not take the junction b while B is about to come through it: it waits at a, B
    passes, and no wait-for cycle forms (before, A took b, and the two waited on each other
    until one was made to step aside)."""
    g: nx.Graph[str] = nx.Graph()
    for n, p in {"a": (0, 0), "b": (2, 0), "c": (4, 0), "d": (6, 0), "s": (2, 2)}.items():
        g.add_node(n, pos=p)
    g.add_edges_from([("a", "b"), ("b", "c"), ("c", "d"), ("b", "s")])
    tm = TrafficManager(g, TrafficParams(deadlock_detect_s=1.0, detect_period_s=0.1))
    tm.add_robot("A", Pose2D(0, 0), 0.0)
    tm.add_robot("B", Pose2D(6, 0), 0.0)
    tm.set_path("A", ["a", "b", "c", "d"], 0.0)
    tm.set_path("B", ["d", "c", "b", "a"], 0.0)
    tm.cycle(0.0)
    assert tm.grant("A").nodes == () and tm.blockers("A") == {"B"}
    assert tm.grant("B").nodes[:2] == ("c", "b")
    pos = {"c": (4, 0), "b": (2, 0), "s": (2, 2), "a": (0, 0)}
    t = 0.0
    for node in ("c", "b"):
        t += 1.0
        tm.update("B", Pose2D(*pos[node]), t)
        tm.cycle(t)
    assert tm.metrics.deadlocks_detected == 0 and tm.metrics.sidesteps == 0
    tm.check()
