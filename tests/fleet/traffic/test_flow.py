"""Errand paths drive with the fleet's flow: the traffic manager's own path planning prefers
the direction of the patrol loops (``TrafficParams.flow_penalty``)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

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


def _aisle_robot() -> tuple[Any, str]:
    """The 6-robot warehouse's traffic policy with robot ``r1`` driving north in aisle 3 of
    the ``aisles_3_4`` loop (clockwise: north in aisle 3, south in aisle 4), 1 m past
    ``a3_1``; and the charger west of aisle 3's south end. The roadmap is not cut into cells
    (``traffic.cell_m``), so the paths below name the warehouse's own nodes."""
    from pathlib import Path

    from fleet.config.loader import load_config
    from fleet.traffic.policy import traffic_from_config
    from fleet.types import Pose2D

    root = Path(__file__).resolve().parents[3]
    config = load_config(root / "configs" / "warehouse_patrol.yaml")
    # the roadmap's own nodes (not cut into cells): the turn-back rule node by node
    config.traffic = dataclasses.replace(config.traffic, cell_m=None)
    policy = traffic_from_config(config)
    m = policy.manager
    m.add_robot("r1", Pose2D(12.0, 9.0, math.pi / 2), 0.0)
    m.set_path(
        "r1", policy.roadmap.expand_route(["a3_s", "a3_n", "a4_n", "a4_s"], closed=True), 0.0, loop=True
    )
    m.cycle(0.0)
    assert m.grant("r1").nodes[-1] == "a3_n"  # the aisle up to its far end
    m.update("r1", Pose2D(12.0, 10.0, math.pi / 2), 1.0)
    m.cycle(1.0)
    return m, "dock:charger:charger1"


def test_a_robot_sent_to_a_charger_turns_back_in_its_aisle_when_nobody_comes() -> None:
    m, charger = _aisle_robot()
    m.set_path("r1", [charger], 1.0, turn_back=True)
    # it gives up the aisle's far end (released), turns back at the next node and drives
    # against the loop's flow to the charger: 4 + 9 + 2 + 1 m instead of about 30 m around
    assert m.path("r1") == ["a3_1", "a3_2", "a3_1", "a3_s", "via:10.00,5.00", charger]
    assert m.holder("a3_n") is None
    m.cycle(1.1)
    assert m.grant("r1").nodes[0] == "a3_2"


def test_an_errand_keeps_the_flow_when_a_robot_comes_the_other_way_or_without_turn_back() -> None:
    from fleet.types import Pose2D

    m, charger = _aisle_robot()
    m.set_path("r1", [charger], 1.0)  # a path that is no errand: the grant is finished first
    assert m.path("r1")[:4] == ["a3_1", "a3_2", "a3_n", "a4_n"]

    m, charger = _aisle_robot()
    m.add_robot("r2", Pose2D(12.0, 5.0, math.pi / 2), 1.0)  # at the aisle's south end ...
    m.set_path("r2", ["a3_s", "a3_1", "a3_2"], 1.0)  # ... about to drive up the aisle
    m.set_path("r1", [charger], 1.0, turn_back=True)
    # no head-on in the aisle: on through its far end (then down aisle 2, where nobody comes)
    assert m.path("r1")[:3] == ["a3_1", "a3_2", "a3_n"]
    assert "a3_s" not in m.path("r1")


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


@settings(max_examples=60, deadline=None)
@given(
    st.integers(min_value=0, max_value=2**31 - 1),
    st.integers(min_value=1, max_value=30),
    st.floats(min_value=0.0, max_value=3.0),
)
def test_compiled_costs_are_the_python_dijkstras_floats(seed: int, n: int, penalty: float) -> None:
    """``RoadIndex.costs_from`` (compiled, rows kept) gives exactly the floats, and the same
    reached nodes, as the plain Python Dijkstra it replaced, before and after the flow
    changes (a kept row must not outlive its flow)."""
    import random

    rng = random.Random(seed)
    g: nx.Graph[str] = nx.Graph()
    names = [f"n{i}" for i in range(n)]
    for name in names:
        g.add_node(name, pos=(rng.uniform(0, 5), rng.uniform(0, 5)))
    for _ in range(2 * n):
        a, b = rng.choice(names), rng.choice(names)  # self-loops and parallel picks included
        g.add_edge(a, b, length=rng.choice([1.0, 0.1, 0.7, 2.5]))
    roads = RoadIndex(g)
    for flow in (False, True, True):
        if flow:
            roads.set_flow([(a, b) for a, b in g.edges if rng.random() < 0.5], rng.choice([penalty, 0.0]))
        for start in rng.sample(names, min(n, 4)) * 2:  # asked twice: the kept row the second time
            want = roads.costs_from_reference(start)
            got = roads.costs_from(start)
            assert dict(got.items()) == want
            assert len(got) == len(want) and set(got) == set(want)
            assert all(got.get(x, math.inf) == want.get(x, math.inf) for x in names)
            assert all((x in got) == (x in want) for x in names + ["nowhere"])


def test_compiled_costs_match_on_a_shipped_floor() -> None:
    from pathlib import Path

    from fleet.config.loader import load_config
    from fleet.traffic.policy import traffic_from_config

    root = Path(__file__).resolve().parents[3]
    policy = traffic_from_config(load_config(root / "configs" / "warehouse_patrol_30.yaml"))
    roads = policy.manager._st.roads
    for start in sorted(roads.pos)[::7]:
        assert dict(roads.costs_from(start).items()) == roads.costs_from_reference(start)


@settings(max_examples=80, deadline=None)
@given(
    st.integers(min_value=0, max_value=2**31 - 1),
    st.integers(min_value=1, max_value=40),
    st.floats(min_value=0.0, max_value=3.0),
)
def test_compiled_astar_returns_the_python_astars_path(seed: int, n: int, penalty: float) -> None:
    """The compiled A* (long searches with nothing to avoid) returns exactly the path of the
    Python A*, ties included (integer grid positions and equal lengths make many), with and
    without a cost limit; so the traffic manager's decisions do not change."""
    import random

    rng = random.Random(seed)
    g: nx.Graph[str] = nx.Graph()
    names = [f"n{rng.randint(0, 99)}_{i}" for i in range(n)]  # names not in index order
    for name in names:
        g.add_node(name, pos=(rng.randint(0, 4), rng.randint(0, 4)))
    for _ in range(2 * n):
        a, b = rng.choice(names), rng.choice(names)
        if rng.random() < 0.5:
            g.add_edge(a, b)  # the straight-line length
        else:
            g.add_edge(a, b, length=float(rng.randint(1, 6)))
    roads = RoadIndex(g)
    roads.set_flow([(a, b) for a, b in g.edges if rng.random() < 0.5], penalty)
    for _ in range(8):
        a, b = rng.choice(names), rng.choice(names)
        limit = rng.choice([math.inf, float(rng.randint(0, 8))])
        want = roads.shortest_reference(a, b, (), limit)
        got = roads._shortest_compiled(a, b, limit) if a != b else [a]
        assert got == want


def test_compiled_astar_on_a_generated_floor(tmp_path: Any) -> None:
    """Every long search of a generated 300-robot floor (with the loops' flow) gives the Python
    A*'s path through :meth:`RoadIndex.shortest`."""
    import random

    from fleet.loadtest.run import prepare_config
    from fleet.traffic.policy import traffic_from_config

    policy = traffic_from_config(prepare_config(300, tmp_path))
    roads = policy.manager._st.roads
    rng = random.Random(3)
    names = sorted(roads.pos)
    for _ in range(40):
        a, b = rng.choice(names), rng.choice(names)
        assert roads.shortest(a, b, frozenset()) == roads.shortest_reference(a, b, frozenset())
    assert roads._heur, "long searches ran compiled"
