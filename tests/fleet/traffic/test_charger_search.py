"""The bounded charger search (``RoadIndex.costs_near``) gives the answers of a search over
the whole roadmap (``RoadIndex.costs_from``) within its reach."""

from __future__ import annotations

import math
import random
from pathlib import Path

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.traffic.errands import first_path
from fleet.traffic.roads import RoadIndex

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


# -- the compiled searches against the Python ones ------------------------------------


def _tie_heavy(seed: int, n: int) -> tuple[RoadIndex, list[str], random.Random]:
    """A random roadmap whose names are not in index order, with equal lengths (many ties),
    self-loops and a flow."""
    rng = random.Random(seed)
    g: nx.Graph[str] = nx.Graph()
    names = [f"n{rng.randint(0, 99)}_{i}" for i in range(n)]
    for name in names:
        g.add_node(name, pos=(rng.randint(0, 4), rng.randint(0, 4)))
    for _ in range(2 * n):
        a, b = rng.choice(names), rng.choice(names)
        g.add_edge(a, b, length=rng.choice([1.0, 1.0, 0.1, 0.7, 2.5]))
    roads = RoadIndex(g)
    roads.set_flow([(a, b) for a, b in g.edges if rng.random() < 0.5], rng.choice([0.0, 0.5, 4.0]))
    return roads, names, rng


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40))
def test_the_compiled_bounded_search_gives_the_python_searchs_floats(seed: int, n: int) -> None:
    """``costs_near`` (compiled) gives the very floats and targets of the Python Dijkstra it
    replaced, at every reach, for targets off the roadmap too; asked again (a kept mask)."""
    roads, names, rng = _tie_heavy(seed, n)
    for _ in range(6):
        here = rng.choice(names)
        targets = rng.sample(names, rng.randint(0, n)) + rng.choice([[], ["nowhere"]])
        reach = rng.choice([0.0, 0.7, 2.0, 10.0, math.inf])
        want = roads.costs_near_reference(here, targets, reach)
        assert roads.costs_near(here, targets, reach) == want
        assert roads.costs_near(here, list(targets), reach) == want


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40))
def test_the_compiled_nearest_gives_the_python_searchs_answer(seed: int, n: int) -> None:
    """``nearest`` (compiled) picks what the Python search picks: least cost, ties to the
    least name, an unreachable or unknown candidate only when nothing is reached."""
    roads, names, rng = _tie_heavy(seed, n)
    for _ in range(6):
        here = rng.choice(names)
        cands = rng.sample(names, rng.randint(0, n)) + rng.choice([[], ["nowhere"]])
        assert roads.nearest(here, cands) == roads.nearest_reference(here, cands)


def test_the_compiled_searches_on_a_generated_floor(tmp_path: Path) -> None:
    """The charger queue's questions on a generated 300-robot floor (with the loops' flow):
    chargers and parking docks from every 50th node, at the queue's reach and unbounded."""
    from fleet.loadtest.run import prepare_config
    from fleet.traffic.errands import CHARGE_REACH_M
    from fleet.traffic.policy import traffic_from_config

    policy = traffic_from_config(prepare_config(300, tmp_path))
    roads = policy.manager._st.roads
    for here in sorted(roads.pos)[::50]:
        for docks in (policy.chargers, policy.parking):
            for reach in (CHARGE_REACH_M, math.inf):
                assert roads.costs_near(here, docks, reach) == roads.costs_near_reference(here, docks, reach)
            assert roads.nearest(here, docks) == roads.nearest_reference(here, docks)


def test_the_traffic_roadmaps_nearest_node_is_the_whole_arrays(tmp_path: Path) -> None:
    """``RoadIndex.nearest_node`` (buckets on a large roadmap: robots register by it) gives the
    node the whole-array ``argmin`` gives: on nodes, near them, between two, off the map."""
    import numpy as np

    from fleet.loadtest.run import prepare_config
    from fleet.roadmap.graph import GRID_FROM_NODES
    from fleet.traffic.policy import traffic_from_config

    roads = traffic_from_config(prepare_config(300, tmp_path)).manager._st.roads
    names = list(roads.pos)
    assert len(names) >= GRID_FROM_NODES
    xy = np.array([roads.pos[n] for n in names])
    rng = np.random.default_rng(7)
    (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
    pts = np.concatenate(
        [xy, xy + rng.normal(0, 0.7, xy.shape), rng.uniform([x0 - 30, y0 - 30], [x1 + 30, y1 + 30], (300, 2))]
        + [(xy[:-1] + xy[1:]) / 2]
    )
    for x, y in pts:
        d2 = (xy[:, 0] - x) ** 2 + (xy[:, 1] - y) ** 2
        assert roads.nearest_node(float(x), float(y)) == names[int(np.argmin(d2))]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40))
def test_the_retarget_searchs_paths_are_single_source_dijkstras(seed: int, n: int) -> None:
    """A side search (``Errands._retarget``) keeps networkx's predecessors instead of every
    path: :func:`first_path` rebuilds, for every node reached, the path
    ``nx.single_source_dijkstra`` gives, and the distances are its floats, with nodes to avoid
    (weight ``None``), ties, zero lengths, self-loops and every reach."""
    _, names, rng = _tie_heavy(seed, n)
    g: nx.Graph[str] = nx.Graph()
    for _ in range(3 * n):
        g.add_edge(rng.choice(names), rng.choice(names), length=rng.choice([1.0, 1.0, 0.1, 0.7, 2.5, 0.0]))
    for _ in range(4):
        here = rng.choice(list(g.nodes))
        avoid = set(rng.sample(list(g.nodes), rng.randint(0, len(g) // 2))) - {here}

        def weight(u: str, v: str, d: dict[str, float], avoid: set[str] = avoid) -> float | None:
            return None if v in avoid else float(d.get("length", 1.0))

        reach = rng.choice([0.0, 0.7, 2.0, math.inf])
        dist, paths = nx.single_source_dijkstra(g, here, cutoff=reach, weight=weight)
        pred, dist2 = nx.dijkstra_predecessor_and_distance(g, here, cutoff=reach, weight=weight)
        assert dist2 == dist and list(dist2) == list(dist)
        assert {v: first_path(pred, here, v) for v in dist} == paths
