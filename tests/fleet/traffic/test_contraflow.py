"""Errands against the flow, reserved end to end (``TrafficParams.contraflow_m``): a robot
sent to a charger round its loop because the short way back was held a moment ago takes
the short way as soon as it is free, and holds all of it until it has passed."""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path
from typing import Any

import pytest

import fleet.traffic.policy as policy_mod
from fleet.config.loader import load_config
from fleet.traffic.contraflow import stretch_end
from fleet.traffic.params import TrafficParams
from fleet.types import Pose2D

ROOT = Path(__file__).resolve().parents[3]
CHARGER = "dock:charger:charger1"


def _sent_round(monkeypatch: pytest.MonkeyPatch, contraflow_m: float) -> Any:
    """The 6-robot warehouse's manager (roadmap not cut into cells, so paths name the
    warehouse's nodes) with ``r1`` driving north in aisle 3 (its loop ``aisles_3_4`` drives
    aisle 3 north, the south corridor west), 1 m past ``a3_1``, sent to the charger west of
    the aisle's south end while ``r2`` stands on ``a3_s`` about to leave westwards: the way
    back down the aisle is held, so ``r1`` is sent on round the loop."""
    monkeypatch.setattr(
        policy_mod, "TrafficParams", functools.partial(TrafficParams, contraflow_m=contraflow_m)
    )
    config = load_config(ROOT / "configs" / "warehouse_patrol.yaml")
    config.traffic = dataclasses.replace(config.traffic, cell_m=None)
    policy = policy_mod.traffic_from_config(config)
    m = policy.manager
    assert m.params.contraflow_m == contraflow_m
    m.add_robot("r1", Pose2D(12.0, 9.0, math.pi / 2), 0.0)
    m.set_path(
        "r1", policy.roadmap.expand_route(["a3_s", "a3_n", "a4_n", "a4_s"], closed=True), 0.0, loop=True
    )
    m.add_robot("r2", Pose2D(12.0, 5.0, math.pi), 0.0)
    m.set_path("r2", ["a3_s", "via:10.00,5.00", "a2_s", "a1_s", "w_s"], 0.0)
    m.cycle(0.0)
    m.update("r1", Pose2D(12.0, 10.0, math.pi / 2), 1.0)
    m.cycle(1.0)
    m.set_path("r1", [CHARGER], 1.0, turn_back=True)
    assert m.path("r1")[:3] == ["a3_1", "a3_2", "a3_n"]  # on round the loop: a3_s is held
    m.cycle(1.1)
    # r2 drives west along the corridor (what it passed is released behind it) before r1
    # has left its aisle
    for t, x in ((1.4, 10.0), (1.7, 9.0), (2.0, 6.0)):
        m.update("r2", Pose2D(x, 5.0, math.pi), t)
        m.update("r1", Pose2D(12.0, 10.0 + (t - 1.0) / 2, math.pi / 2), t)
        m.cycle(t)
    assert m.holder("a3_s") is None and m.holder("via:10.00,5.00") is None
    return m


def test_an_errand_takes_the_short_way_once_free_and_holds_it_end_to_end(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    m = _sent_round(monkeypatch, contraflow_m=30.0)
    assert m.shorten_errand("r1", 2.0)
    # it turns back at a3_2 (the first node it can still stop before) and drives the aisle
    # south, against the flow, to the corridor and the charger beside it
    assert m.path("r1") == ["a3_1", "a3_2", "a3_1", "a3_s", "via:10.00,5.00", CHARGER]
    # the whole stretch against the flow, and the node after it, are its own at once
    for node in ("a3_1", "a3_s", "via:10.00,5.00"):
        assert m.holder(node) == "r1"
    assert m.holder("a3_n") is None  # the loop's way on, given back
    # a robot coming along the corridor cannot drive into the stretch head-on
    m.add_robot("r3", Pose2D(15.0, 5.0, math.pi), 2.0)
    m.set_path("r3", ["a4_s", "a3_s", "via:10.00,5.00"], 2.0)
    m.cycle(2.1)
    assert m.holder("a3_s") == "r1"
    assert "r1" in m.blockers("r3")
    m.check()


def test_without_the_rule_the_errand_keeps_the_long_way(monkeypatch: pytest.MonkeyPatch) -> None:
    m = _sent_round(monkeypatch, contraflow_m=0.0)
    assert not m.shorten_errand("r1", 2.0)
    assert m.path("r1")[:3] == ["a3_1", "a3_2", "a3_n"]


def test_a_stretch_longer_than_the_limit_is_not_taken(monkeypatch: pytest.MonkeyPatch) -> None:
    m = _sent_round(monkeypatch, contraflow_m=5.0)  # the way back is 4 + 4 + 5 + 2 m
    assert not m.shorten_errand("r1", 2.0)
    assert m.path("r1")[:3] == ["a3_1", "a3_2", "a3_n"]


def test_the_stretch_ends_one_node_past_the_last_step_against_the_flow() -> None:
    import networkx as nx

    from fleet.traffic.roads import RoadIndex

    g: nx.Graph[str] = nx.Graph()
    for i in range(5):
        g.add_node(str(i), pos=(float(i), 0.0))
    g.add_edges_from([(str(i), str(i + 1)) for i in range(4)])
    roads = RoadIndex(g)
    roads.set_flow([("1", "0"), ("2", "1")], penalty=3.0)  # 0-1-2 driven westwards
    assert stretch_end(roads, ["0", "1", "2", "3", "4"]) == 3
    assert stretch_end(roads, ["2", "3", "4"]) == 0  # nothing against the flow
    assert stretch_end(roads, ["0", "1", "2"]) == 2  # to the way's end
