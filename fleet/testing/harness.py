"""What conformance cases are made of: the harness a backend brings (:class:`ConformanceHarness`,
:class:`ConformanceWorld`, :data:`HarnessFactory`), the capabilities a backend may lack
(:data:`CAPABILITIES`), :class:`Case`, and the helpers cases use (:func:`expect`,
:func:`wait_for`, :func:`finish`, :func:`robot_pose`). :mod:`fleet.testing.conformance` runs
the cases and re-exports these names."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Protocol

from fleet.navigation import NavigationBackend
from fleet.types import GoalState, Pose2D


@dataclass(frozen=True)
class ConformanceWorld:
    """What a conformance case may assume about the harness's world (``map`` frame, m, rad).

    ``reachable`` is free and reachable from ``start`` within ``nav_time_s`` seconds;
    ``occupied`` lies inside a static obstacle (GOAL_OCCUPIED); ``off_map`` is outside the map
    (GOAL_OUTSIDE_MAP); ``unreachable`` is free but enclosed (NO_VALID_PATH);
    ``free_behind_m`` is the free straight distance behind ``start`` (for BackUp).
    ``goal_tolerance`` / ``yaw_tolerance`` are the backend's goal-checker tolerances.
    """

    start: Pose2D
    reachable: Pose2D
    occupied: Pose2D
    off_map: Pose2D
    unreachable: Pose2D
    free_behind_m: float
    goal_tolerance: float
    yaw_tolerance: float
    nav_time_s: float = 60.0


class ConformanceHarness(Protocol):
    """One robot behind a backend under test, in a known world (see the module docstring)."""

    @property
    def backend(self) -> NavigationBackend: ...

    @property
    def world(self) -> ConformanceWorld: ...

    def advance(self, seconds: float) -> None: ...


#: Makes a fresh harness for one case: a context manager yielding it and cleaning up on exit.
HarnessFactory = Callable[[], AbstractContextManager[ConformanceHarness]]

#: Capabilities a case may require. A backend that ``lacks`` one is not checked for it.
CAPABILITIES: dict[str, str] = {
    "occupancy_map": "knows static obstacles, so a goal inside one aborts with GOAL_OCCUPIED",
    "spin_in_place": "can turn on the spot (Spin)",
    "reverse": "can drive backwards (BackUp)",
    "path_following": "can drive along a free path it is given (FollowPath)",
    "costmaps": "keeps costmaps a ClearCostmaps goal clears",
}


class CaseFailed(Exception):
    """A case found the backend breaking the contract (the message says how)."""


def expect(condition: bool, reason: str) -> None:
    """Fail the running case with ``reason`` unless ``condition`` holds."""
    if not condition:
        raise CaseFailed(reason)


def wait_for(
    harness: ConformanceHarness, predicate: Callable[[], bool], timeout_s: float, step_s: float = 0.1
) -> bool:
    """Advance the harness in ``step_s`` increments until ``predicate()`` holds or
    ``timeout_s`` of backend time passed; return whether it held."""
    waited = 0.0
    while not predicate():
        if waited >= timeout_s - 1e-9:
            return False
        harness.advance(step_s)
        waited += step_s
    return True


@dataclass(frozen=True)
class Case:
    """One conformance case: ``check(harness)`` fails (raises) when the backend breaks the
    contract. ``requires`` names capabilities of :data:`CAPABILITIES`."""

    name: str
    check: Callable[[ConformanceHarness], None]
    requires: frozenset[str] = frozenset()

    @property
    def doc(self) -> str:
        """What the case checks (the first line of its docstring)."""
        text = (self.check.__doc__ or self.name).strip().split("\n\n")[0]
        return " ".join(text.split())


def finish(h: ConformanceHarness, goal_id: str, timeout_s: float) -> GoalState:
    """Wait up to ``timeout_s`` for goal ``goal_id`` to end (the case fails if it does not);
    return its terminal state."""
    ok = wait_for(h, lambda: h.backend.goal_state(goal_id).status.terminal, timeout_s)
    state = h.backend.goal_state(goal_id)
    expect(ok, f"goal {goal_id} still {state.status.value} after {timeout_s} s")
    return state


def robot_pose(h: ConformanceHarness) -> Pose2D:
    """The robot's pose (the case fails if it is not localized)."""
    pose = h.backend.robot_state().pose
    expect(pose is not None, "the harness robot must be localized (robot_state().pose is None)")
    assert pose is not None
    return pose


def case_registry() -> tuple[
    list[Case],
    Callable[..., Callable[[Callable[[ConformanceHarness], None]], Callable[[ConformanceHarness], None]]],
]:
    """A list of cases and a decorator ``@case(*requires)`` appending a check function to it
    as a :class:`Case` named after the function."""
    cases: list[Case] = []

    def case(
        *requires: str,
    ) -> Callable[[Callable[[ConformanceHarness], None]], Callable[[ConformanceHarness], None]]:
        def register(check: Callable[[ConformanceHarness], None]) -> Callable[[ConformanceHarness], None]:
            cases.append(Case(check.__name__, check, frozenset(requires)))
            return check

        return register

    return cases, case
