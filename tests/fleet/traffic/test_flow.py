"""Errand paths drive with the fleet's flow: the traffic manager's own path planning prefers
the direction of the patrol loops (``TrafficParams.flow_penalty``)."""

from __future__ import annotations

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.traffic.roads import RoadIndex


def _square() -> nx.Graph[str]:
    g: nx.Graph[str] = nx.Graph()
    for n, xy in {"a": (0, 0), "b": (1, 0), "c": (1, 1), "d": (0, 1)}.items():
        g.add_node(n, pos=xy)
    g.add_edges_from([("a", "b"), ("b", "c"), ("c", "d"), ("d", "a")])
    return g


def test_paths_go_with_the_flow_unless_the_detour_costs_more_than_the_penalty() -> None:
    roads = RoadIndex(_square())
    assert roads.shortest("b", "a", set()) == ["b", "a"]
    roads.set_flow([("a", "b"), ("b", "c"), ("c", "d"), ("d", "a")], penalty=3.0)
    assert roads.shortest("b", "a", set()) == ["b", "c", "d", "a"]  # 3 m with the flow < 4 m against
    assert roads.costs_from("b")["a"] == 3.0
    roads.set_flow([("a", "b"), ("b", "c"), ("c", "d"), ("d", "a")], penalty=1.0)
    assert roads.shortest("b", "a", set()) == ["b", "a"]  # 2 m against < 3 m around
    roads.set_flow([("a", "b"), ("b", "a")], penalty=3.0)  # driven both ways: no preference
    assert roads.shortest("b", "a", set()) == ["b", "a"]


def test_a_shipped_config_gives_its_patrol_loops_direction() -> None:
    from pathlib import Path

    from fleet.config.loader import load_config
    from fleet.traffic.policy import traffic_from_config

    root = Path(__file__).resolve().parents[3]
    policy = traffic_from_config(load_config(root / "configs" / "warehouse_patrol.yaml"))
    costs = policy.manager.costs_from("a1_s")
    # aisle 1 is driven north in its loop: south-bound costs more than its length
    assert policy.manager.costs_from("a1_n")["a1_s"] > costs["a1_n"]


@settings(max_examples=60, deadline=None)
@given(
    st.integers(min_value=0, max_value=2**31 - 1),
    st.integers(min_value=2, max_value=30),
    st.floats(min_value=0.0, max_value=3.0),
)
def test_the_nearest_candidate_is_the_least_of_the_full_costs(seed: int, n: int, penalty: float) -> None:
    """``RoadIndex.nearest`` stops its search early: it must pick what the whole-roadmap costs
    pick, ties (equal lengths on a grid) and unreachable candidates included."""
    import math
    import random

    rng = random.Random(seed)
    g: nx.Graph[str] = nx.Graph()
    names = [f"n{i}" for i in range(n)]
    for name in names:  # integer grid positions: many equal path lengths
        g.add_node(name, pos=(rng.randint(0, 4), rng.randint(0, 4)))
    for _ in range(2 * n):
        a, b = rng.sample(names, 2)
        g.add_edge(a, b)
    roads = RoadIndex(g)
    roads.set_flow([(a, b) for a, b in g.edges if rng.random() < 0.5], penalty)
    for _ in range(5):
        start = rng.choice(names)
        cands = rng.sample(names, rng.randint(0, n))
        costs = roads.costs_from(start)
        want = min(cands, key=lambda c: (costs.get(c, math.inf), c)) if cands else None
        assert roads.nearest(start, cands) == want
