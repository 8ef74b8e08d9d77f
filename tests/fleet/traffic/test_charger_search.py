"""The bounded charger search (``RoadIndex.costs_near``) gives the answers of a search over
the whole roadmap (``RoadIndex.costs_from``) within its reach."""

from __future__ import annotations

import math
import random

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

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
