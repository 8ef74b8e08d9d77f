"""Fixtures of the behavior-tree tests (helpers live in ``nodes_world.py``)."""

from __future__ import annotations

from collections.abc import Iterator

import py_trees
import pytest

from fleet.robots import BatteryModel


@pytest.fixture(autouse=True)
def clean_blackboard() -> Iterator[None]:
    """Each test starts and ends with an empty process-global blackboard."""
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


@pytest.fixture
def fast_battery() -> BatteryModel:
    """A battery that drains 5 % per meter and charges 20 % per second (goes to charge below
    30 % or the energy of the Manhattan way to the charger, no margin)."""
    return BatteryModel(
        drain_per_m=0.05,
        drain_per_s=0.0,
        charge_per_s=0.2,
        low=0.3,
        resume=0.9,
        reserve=0.0,
        margin=0.0,
        detour=1.0,
    )
