"""A robot stepping aside must not stop inside an aisle another robot is about to drive
down (``TrafficParams.sidestep_clear_corridor``): the shape of every deadlock episode of the
100-robot load test with roadmap cells (``docs/traffic.md``, "Side steps")."""

from __future__ import annotations

import networkx as nx
from node_hops import hop_to_goals

from fleet.roadmap.graph import Roadmap
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.types import Pose2D

# a - b - c - d along the main corridor (d a dead end); at the junction b an aisle goes north,
# b - x1 - x2 - e (x1, x2 its cells), a bay s and a spur n where C waits.
NODES = {
    "a": (0.0, 0.0),
    "b": (2.0, 0.0),
    "c": (4.0, 0.0),
    "d": (6.0, 0.0),
    "x1": (2.0, 1.5),
    "x2": (2.0, 3.0),
    "e": (2.0, 4.5),
    "f": (0.0, 4.5),
    "g": (4.0, 4.5),
    "s": (3.5, 1.5),
    "n": (2.0, -2.0),
}
# the aisle's first cell comes before the bay among b's neighbours: the nearest free node
EDGES = [
    ("a", "b"),
    ("b", "c"),
    ("c", "d"),
    ("b", "x1"),
    ("x1", "x2"),
    ("x2", "e"),
    ("e", "f"),
    ("e", "g"),
    ("b", "s"),
    ("n", "b"),
]
GOALS = {"A": "d", "B": "a", "C": "e"}


def _world(clear: bool) -> TrafficManager:
    g: nx.Graph[str] = nx.Graph()
    for name, xy in NODES.items():
        g.add_node(name, pos=xy)
    g.add_edges_from(EDGES)
    params = TrafficParams(
        deadlock_detect_s=1.0, detect_period_s=0.1, sidestep_clear_corridor=8 if clear else 0
    )
    tm = TrafficManager(Roadmap.from_graph(g), params)
    # A stands on the junction b heading east; B comes west from the dead end d: a head-on
    # pair. C waits on the spur n to drive up the aisle, behind A's node b; it ranks above A
    # (it takes b before A comes back to it).
    for name, node, prio in (("A", "b", 0.0), ("B", "d", 0.0), ("C", "n", 50.0)):
        tm.add_robot(name, Pose2D(*NODES[node], 0.0), 0.0, priority=prio)
    tm.set_path("A", ["b", "c", "d"], 0.0)
    tm.set_path("B", ["d", "c", "b", "a"], 0.0)
    tm.set_path("C", ["n", "b", "x1", "x2", "e"], 0.0)
    return tm


def _drive(tm: TrafficManager, until_s: float) -> tuple[float, str | None]:
    """:func:`hop_to_goals`: the time everyone arrived (``until_s`` if not) and where A
    stepped aside."""
    stepped: list[str] = []

    def hop(name: str, node: str) -> None:
        if name == "A" and not stepped and node not in ("c", "d"):
            stepped.append(node)

    t = hop_to_goals(tm, GOALS, until_s, on_hop=hop)
    return t, (stepped[0] if stepped else None)


def test_side_step_into_an_aisle_a_robot_is_about_to_enter_deadlocks_again() -> None:
    tm = _world(clear=False)
    t, stepped = _drive(tm, 60.0)
    # A steps into the aisle's first cell; C takes b behind it and waits for that cell
    # while A waits for b: a second wait-for cycle, and A is pushed up the aisle
    assert stepped == "x1"
    assert tm.metrics.deadlocks_detected >= 2
    assert t > 2.0 * _drive(_world(clear=True), 60.0)[0]


def test_side_step_leaves_the_aisle_free_and_everyone_arrives() -> None:
    tm = _world(clear=True)
    t, stepped = _drive(tm, 60.0)
    assert stepped == "s"  # the bay, off every robot's way
    assert tm.metrics.deadlocks_detected == 1 and tm.metrics.deadlocks_resolved == 1
    assert t < 60.0, {n: (tm.path(n), tm.blockers(n)) for n in GOALS}


def _line(deep: int) -> TrafficManager:
    # one corridor n0 .. n8, and at n0 a bay s and the way on west, w; B stands on the dead
    # end n8 heading to w, A in the middle heading east: the only free node off B's way is
    # the bay, 5 edges from A
    g: nx.Graph[str] = nx.Graph()
    for i in range(9):
        g.add_node(f"n{i}", pos=(2.0 * i, 0.0))
    g.add_node("s", pos=(0.0, 2.0))
    g.add_node("w", pos=(-2.0, 0.0))
    g.add_edges_from([(f"n{i}", f"n{i + 1}") for i in range(8)] + [("n0", "s"), ("n0", "w")])
    params = TrafficParams(deadlock_detect_s=1.0, detect_period_s=0.1, sidestep_deep_depth=deep)
    tm = TrafficManager(Roadmap.from_graph(g), params)
    tm.add_robot("A", Pose2D(8.0, 0.0, 0.0), 0.0)
    tm.add_robot("B", Pose2D(16.0, 0.0, 0.0), 0.0)
    tm.set_path("A", ["n4", "n5", "n6", "n7", "n8"], 0.0)
    tm.set_path("B", [f"n{i}" for i in range(8, -1, -1)] + ["w"], 0.0)
    return tm


def _run_line(tm: TrafficManager, until_s: float) -> bool:
    t = 0.0
    while t < until_s:
        tm.cycle(t)
        for name in ("A", "B"):
            nodes = tm.grant(name).nodes
            if nodes:
                tm.update(name, Pose2D(*tm.node_pos(nodes[0]), 0.0), t)
        tm.check()
        if tm.done("A") and tm.done("B") and tm.path("A")[-1] == "n8" and tm.path("B")[-1] == "w":
            return True
        t = round(t + 0.1, 6)
    return False


def test_a_deeper_side_step_resolves_a_head_on_pair_with_no_free_node_nearby() -> None:
    assert not _run_line(_line(deep=0), 30.0)  # within sidestep_depth (4) edges: nothing
    tm = _line(deep=8)
    assert _run_line(tm, 30.0)
    assert any("A stepped aside to s" in msg for _, msg in tm.metrics.events)
