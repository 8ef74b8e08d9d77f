"""Travel costs along the roadmap, the greedy min-cost matching and its ranking rules, and the
charger each robot is given."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fleet.coordination.matching import (
    CHARGER_BONUS_M,
    COOLDOWN_PENALTY,
    PREFERRED_RANK,
    ChargerAllocation,
    greedy_match,
    rank,
    travel_costs,
)
from fleet.coordination.views import Observation, RobotView
from fleet.roadmap.distances import Distances
from fleet.roadmap.graph import Roadmap
from fleet.types import Pose2D


def line() -> Distances:
    """a(0) - b(10) - c(20) along x, and an island node z far away."""
    rm = Roadmap.from_config_dict(
        {
            "nodes": {"a": [0, 0], "b": [10, 0], "c": [20, 0], "z": [0, 50], "y": [1, 50]},
            "edges": [["a", "b"], ["b", "c"], ["z", "y"]],
        }
    )
    return Distances(rm)


def view(name: str, x: float, y: float = 0.0) -> RobotView:
    return RobotView(name, obs=Observation(t=0.0, pose=Pose2D(x, y)))


def test_costs_follow_the_roadmap_to_the_nearest_entry() -> None:
    d = line()
    i = d.index
    entries = np.array([[i["a"], i["c"]], [i["z"], i["z"]], [i["b"], i["b"]]], dtype=np.int64)
    off = np.array([[0.0, 0.0], [0.0, 0.0], [2.5, 2.5]])
    costs, entry = travel_costs(d, [Pose2D(18, 1), Pose2D(9, 0)], entries, off)
    # robot 0 snaps to c (hypot(2, 1)), enters the first task at c; task 2 is b + 2.5 m
    assert costs[0, 0] == pytest.approx(math.hypot(2, 1)) and entry[0, 0] == 1
    assert math.isinf(costs[0, 1])  # z is not connected
    assert costs[0, 2] == pytest.approx(math.hypot(2, 1) + 10 + 2.5)
    # robot 1 snaps to b (1 m); a and c are both 10 m on: a tie goes to the first entry
    assert costs[1, 0] == pytest.approx(11.0) and entry[1, 0] == 0
    same, _ = travel_costs(d, [Pose2D(18, 1)], entries[:1], np.zeros((1, 2)), offsets=False)
    assert same[0, 0] == costs[0, 0]


def test_greedy_matching_is_global_and_skips_unreachable() -> None:
    inf = math.inf
    # row 0 is listed first and cheapest for column 0, but (1, 0) is cheaper still
    ranks = np.array([[2.0, 3.0, inf], [1.0, 9.0, inf], [inf, inf, inf]])
    assert greedy_match(ranks) == [(1, 0), (0, 1)]
    assert greedy_match(np.array([[1.0, 1.0], [1.0, 1.0]])) == [(0, 0), (1, 1)]  # ties: row-major
    assert greedy_match(np.zeros((0, 3))) == []


def test_rank_charger_bonus_cooldown_and_preferred_robot() -> None:
    chargers = ChargerAllocation([Pose2D(0, 0)])
    on_charger, cooling, plain = view("on", 0.2), view("cool", 5), view("plain", 5)
    cooling.cooldown_until = 10.0
    costs = np.array([[4.0, 4.0], [1.0, 1.0], [2.0, math.inf]])
    r = rank(costs, [on_charger, cooling, plain], [None, "plain"], chargers, now=5.0)
    assert list(r[0]) == [4.0 - CHARGER_BONUS_M] * 2
    assert list(r[1]) == [1.0 + COOLDOWN_PENALTY] * 2
    assert r[2, 0] == 2.0 and math.isinf(r[2, 1])  # unreachable: not preferred after all
    r = rank(costs, [on_charger, cooling, plain], ["plain", None], chargers, now=10.0)
    assert r[2, 0] == PREFERRED_RANK and r[1, 0] == 1.0  # cool-down over
    assert costs[1, 0] == 1.0  # the costs are not modified


def test_chargers_near_the_work_by_travel_distance_shared_with_a_penalty() -> None:
    # a U: chargers at both tips (0, 0) and (0, 20); the straight line from x to the far tip
    # is short (20 m), the way along the roadmap long (100 m)
    rm = Roadmap.from_config_dict(
        {
            "nodes": {"c1": [0, 0], "p": [40, 0], "q": [40, 20], "c2": [0, 20], "w": [38, 20]},
            "edges": [["c1", "p"], ["p", "q"], ["q", "w"], ["w", "c2"]],
        }
    )
    chargers = ChargerAllocation([Pose2D(0, 0), Pose2D(0, 20)], Distances(rm))
    a, b, c = view("a", 38, 20), view("b", 38, 20), view("c", 38, 20)
    assert chargers.charger_for(a, ["p"]) == Pose2D(0, 0)  # 40 m, not 80 m by the way
    assert chargers.charger_for(a) == Pose2D(0, 0)  # kept without new work
    assert chargers.charger_for(a, ["p"]) == Pose2D(0, 0) and chargers.load == [1, 0]
    # the work's mean distance: w is 38 m from c2 and 62 m from c1, q 40 / 60
    assert chargers.charger_for(b, ["q", "w"]) == Pose2D(0, 20)
    # a second robot near c1: the shared charger looks SHARE_PENALTY_M farther, still nearer
    assert chargers.charger_for(c, ["c1"]) == Pose2D(0, 0) and chargers.load == [2, 1]
    # new work: a gives its charger back and takes the one near its new work
    assert chargers.charger_for(a, ["w"]) == Pose2D(0, 20) and chargers.load == [1, 2]
    chargers.free(a)
    assert a.charger is None and chargers.load == [1, 1]
    # without work: the robot's nearest node (w, 38 m from c2)
    assert chargers.charger_for(view("d", 38, 20)) == Pose2D(0, 20)


def test_chargers_without_a_roadmap_go_by_straight_line_and_load() -> None:
    chargers = ChargerAllocation([Pose2D(0, 0), Pose2D(100, 0)])
    a, b, c = view("a", 90), view("b", 95), view("c", 50)
    assert chargers.charger_for(a) == Pose2D(100, 0)
    assert chargers.charger_for(b) == Pose2D(100, 0)  # 5 m + one robot's penalty < 95 m
    assert chargers.charger_for(c) == Pose2D(0, 0)  # 50 m < 50 m + two robots' penalty
    assert chargers.load == [1, 2]
    assert ChargerAllocation([]).charger_for(c) is None
    assert chargers.on_charger(view("x", 100.4)) and not chargers.on_charger(view("x", 100.6))


def test_a_dead_robot_s_charger_counts_as_free_in_the_next_choice() -> None:
    chargers = ChargerAllocation([Pose2D(0, 0), Pose2D(100, 0)])
    a, b = view("a", 90), view("b", 95)
    assert chargers.charger_for(a) == chargers.charger_for(b) == Pose2D(100, 0)
    chargers.free(a)
    chargers.free(b)  # both died: the far charger is empty again
    assert chargers.load == [0, 0]
    assert chargers.charger_for(view("c", 60)) == Pose2D(100, 0)  # 40 m, no penalty left
