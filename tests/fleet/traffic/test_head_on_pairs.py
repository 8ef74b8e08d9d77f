"""Two robots head-on on neighbouring junctions are resolved at once when
``TrafficParams.swap_detect_s`` is set, not after ``deadlock_detect_s``: such a pair can never
move on its own (the transient wait-for cycles of the 100-robot load test's cross corridors,
``docs/traffic.md``, "Head-on pairs")."""

from __future__ import annotations

import networkx as nx
from node_hops import hop_to_goals

from fleet.roadmap.graph import Roadmap
from fleet.traffic.deadlocks import head_on_pairs
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.types import Pose2D

# a corridor w - a - b - e; a and b are junctions (a bay below each)
NODES = {"w": (0.0, 0.0), "a": (2.0, 0.0), "b": (4.0, 0.0), "e": (6.0, 0.0)}
NODES |= {"pa": (2.0, -2.0), "pb": (4.0, -2.0)}
GOALS = {"A": "e", "B": "w"}


def _world(swap_s: float | None) -> TrafficManager:
    g: nx.Graph[str] = nx.Graph()
    for name, xy in NODES.items():
        g.add_node(name, pos=xy)
    g.add_edges_from([("w", "a"), ("a", "b"), ("b", "e"), ("a", "pa"), ("b", "pb")])
    params = TrafficParams(deadlock_detect_s=2.0, detect_period_s=0.1, swap_detect_s=swap_s)
    tm = TrafficManager(Roadmap.from_graph(g), params)
    tm.add_robot("A", Pose2D(*NODES["a"], 0.0), 0.0)
    tm.add_robot("B", Pose2D(*NODES["b"], 0.0), 0.0)
    tm.set_path("A", ["a", "b", "e"], 0.0)
    tm.set_path("B", ["b", "a", "w"], 0.0)
    return tm


def _drive(tm: TrafficManager, until_s: float) -> tuple[float | None, float]:
    """:func:`hop_to_goals`: when the first deadlock was handled, and when both arrived
    (``until_s`` if not)."""
    first: list[float] = []

    def seen(t: float) -> None:
        if not first and tm.metrics.deadlocks_detected:
            first.append(t)

    t = hop_to_goals(tm, GOALS, until_s, after_cycle=seen)
    return (first[0] if first else None), t


def test_a_head_on_pair_waits_for_the_deadlock_timer_without_the_rule() -> None:
    first, t = _drive(_world(None), 30.0)
    assert first is not None and first >= 2.0
    assert t < 30.0


def test_a_head_on_pair_is_resolved_at_once_with_the_rule() -> None:
    tm = _world(0.3)
    tm.cycle(0.0)  # each asks for the node the other stands on
    assert head_on_pairs(tm._st, 0.2, 0.3) == []  # noqa: SLF001 - the manager's state
    assert head_on_pairs(tm._st, 0.3, 0.3) == [{"A", "B"}]  # noqa: SLF001
    first, t = _drive(_world(0.3), 30.0)
    assert first is not None and first < 1.0
    slow = _drive(_world(None), 30.0)[1]
    assert t < slow and t < 30.0
