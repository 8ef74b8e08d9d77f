"""The conformance checker as users run it (``check_backend``): a conforming backend passes, a
backend that breaks the contract is reported by case with the reason, capabilities skip cases."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from conformance_harness import SimHarness, sim_harness

from fleet.navigation import NavigationBackend
from fleet.testing.conformance import (
    CAPABILITIES,
    CASES,
    ConformanceHarness,
    Outcome,
    check_backend,
)
from fleet.types import FollowWaypoints, Goal, GoalState, GoalStatus, RobotState

DOCS = Path(__file__).resolve().parents[3] / "docs" / "testing.md"


def _cases(*names: str) -> list:
    by_name = {c.name: c for c in CASES}
    return [by_name[n] for n in names]


def test_the_simulator_passes_every_case() -> None:
    report = check_backend(sim_harness)
    assert report.ok, str(report)
    assert [r.name for r in report.results] == [c.name for c in CASES]
    assert f"{len(CASES)} passed, 0 failed, 0 skipped" in str(report)


@dataclass
class _RejectsEmptyWaypoints:
    """The SUMO backend's old behaviour: an empty FollowWaypoints is REJECTED."""

    inner: NavigationBackend

    @property
    def namespace(self) -> str:
        return self.inner.namespace

    def send_goal(self, goal: Goal) -> str:
        if isinstance(goal, FollowWaypoints) and not goal.poses:
            return "rejected#1"
        return self.inner.send_goal(goal)

    def goal_state(self, goal_id: str) -> GoalState:
        if goal_id == "rejected#1":
            return GoalState(goal_id, "follow_waypoints", GoalStatus.REJECTED, error_msg="no poses")
        return self.inner.goal_state(goal_id)

    def cancel_goal(self, goal_id: str) -> None:
        self.inner.cancel_goal(goal_id)

    def robot_state(self) -> RobotState:
        return self.inner.robot_state()


@contextmanager
def _drifted() -> Iterator[ConformanceHarness]:
    with sim_harness() as h:
        assert isinstance(h, SimHarness)
        yield SimHarness(h.sim, _RejectsEmptyWaypoints(h.backend), h.world)


def test_a_backend_breaking_the_contract_is_named_with_the_reason() -> None:
    report = check_backend(
        _drifted, cases=_cases("empty_follow_waypoints_aborts", "wait_succeeds_after_its_duration")
    )
    assert not report.ok
    (failure,) = report.failures
    assert failure.name == "empty_follow_waypoints_aborts"
    assert failure.reason == "an empty FollowWaypoints ended rejected"
    assert "FAILED  empty_follow_waypoints_aborts: an empty FollowWaypoints ended rejected" in str(report)
    assert report.results[1].outcome is Outcome.PASSED


def test_a_harness_that_cannot_start_fails_every_case_with_its_error() -> None:
    @contextmanager
    def broken() -> Iterator[ConformanceHarness]:
        raise OSError("no simulator here")
        yield  # pragma: no cover

    report = check_backend(broken, cases=_cases("satisfies_protocol"))
    assert report.failures[0].reason == "raised OSError: no simulator here"


def test_lacked_capabilities_skip_their_cases_with_the_reason() -> None:
    lacks = {"reverse": "a forklift cannot back up here"}
    report = check_backend(sim_harness, lacks=lacks, cases=_cases("backup_succeeds_and_moves_backwards"))
    (result,) = report.results
    assert result.outcome is Outcome.SKIPPED and report.ok
    assert result.reason == "lacks reverse: a forklift cannot back up here"
    with pytest.raises(ValueError, match="unknown capabilities"):
        check_backend(sim_harness, lacks={"fly": "no wings"})
    assert {c for case in CASES for c in case.requires} <= set(CAPABILITIES)


def test_every_case_says_what_it_checks() -> None:
    assert len({c.name for c in CASES}) == len(CASES)
    assert all(c.doc and not c.doc.startswith(c.name) for c in CASES)


def test_the_example_in_docs_testing_md_runs(tmp_path: Path) -> None:
    code = re.search(r"```python\n(.*?)```", DOCS.read_text(), re.S)
    assert code is not None
    script = tmp_path / "example.py"
    script.write_text(code.group(1))
    root = str(DOCS.parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"backend conformance: {len(CASES)} passed, 0 failed, 0 skipped" in done.stdout
