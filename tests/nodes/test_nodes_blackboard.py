"""Per-robot blackboards: namespaces, defaults, independence."""

from __future__ import annotations

import py_trees
import pytest

from fleet.types import Pose2D
from nodes.blackboard import (
    DEFAULTS,
    clear_robot_blackboard,
    key_path,
    normalize_namespace,
    read_key,
    robot_blackboard,
)


def test_robot_blackboard_has_every_key_with_defaults() -> None:
    bb = robot_blackboard("robot1")
    for key, default in DEFAULTS.items():
        assert bb.get(key) == default
        assert py_trees.blackboard.Blackboard.exists(f"/robot1/{key}")
    for key in ("route", "task_id", "pick", "charger", "laps", "lap_task_id", "active_leaf", "mode"):
        assert key in DEFAULTS
    assert "route_progress" in DEFAULTS and "picks_done" in DEFAULTS


def test_existing_values_are_kept_and_robots_are_independent() -> None:
    a = robot_blackboard("/robot1", name="agent1")
    a.laps = 3
    a.route = (Pose2D(1.0, 2.0),)
    again = robot_blackboard("/robot1", name="tree1")
    other = robot_blackboard("/robot2", name="agent2")
    assert again.laps == 3 and again.route == (Pose2D(1.0, 2.0),)
    assert other.laps == 0 and other.route is None
    other.laps = 7
    assert a.laps == 3
    assert read_key("/robot2", "laps")() == 7
    assert read_key("/robot9", "mode")() == "idle"  # never written: the default


def test_namespaces_and_clearing() -> None:
    assert normalize_namespace("robot1/") == "/robot1"
    assert key_path("/fleet/robot1", "laps") == "/fleet/robot1/laps"
    with pytest.raises(ValueError):
        normalize_namespace("/")
    bb = robot_blackboard("/robot1")
    robot_blackboard("/robot10").laps = 5
    bb.laps = 2
    clear_robot_blackboard("/robot1")
    assert not py_trees.blackboard.Blackboard.exists("/robot1/laps")
    assert py_trees.blackboard.Blackboard.get("/robot10/laps") == 5
