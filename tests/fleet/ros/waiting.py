"""Waiting in the ROS tests: on a condition, with a deadline, never a fixed sleep."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

#: Hang guard (wall s) for discovery and one short goal: discovery takes 0.1-0.5 s on an idle
#: machine and several seconds on a loaded 2-core one.
DISCOVERY_S = 60.0
#: Hang guard (wall s) for one goal of a few meters at the test server's speed.
GOAL_S = 60.0


def wait_until(predicate: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.02) -> None:
    """Return as soon as ``predicate()`` is true; fail the test naming ``what`` after
    ``timeout_s`` wall seconds (a hang guard: several times the time on a loaded machine)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"{what}: not within {timeout_s:.0f} s")
        time.sleep(poll_s)
