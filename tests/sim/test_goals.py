"""The Nav2 goal semantics shared by the simulator and SUMO (sim/goals.py): ids, validation,
reject reasons, start errors, records, preemption, and what the simulator does with them."""

from __future__ import annotations

import math

import pytest
from sim_testworld import advance, make_sim

from fleet.errors import BackendError
from fleet.types import (
    BackUp,
    DriveOnHeading,
    ErrorCode,
    FollowWaypoints,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
)
from sim.goals import KEEP_FINISHED, GoalBook, preempt, reject_if_invalid, reject_reason, start_error


class NotAGoal:
    kind = "teleport"


def test_ids_count_per_robot_and_a_non_goal_spends_no_id() -> None:
    book = GoalBook()
    assert book.open("/a", Wait(1.0)).goal_id == "/a#1"
    assert book.open("/b", Wait(1.0)).goal_id == "/b#1"
    with pytest.raises(BackendError, match="NotAGoal is not a navigation goal"):
        book.open("/a", NotAGoal())
    assert book.open("/a", Wait(1.0)).goal_id == "/a#2"
    with pytest.raises(KeyError):
        book.get("/a#3")


def test_the_book_forgets_the_oldest_finished_goals_beyond_its_limit_but_never_reuses_ids() -> None:
    book = GoalBook(keep_finished=2)
    records = []
    for _ in range(5):
        if records:
            records[-1].finish(GoalStatus.SUCCEEDED)
        records.append(book.open("/a", Wait(1.0)))
    assert [r.goal_id for r in records] == [f"/a#{n}" for n in range(1, 6)]
    with pytest.raises(KeyError):
        book.get("/a#2")
    assert book.get("/a#3").status is GoalStatus.SUCCEEDED
    assert book.live("/a#5") is records[-1] and book.live("/a#4") is None and book.live("/x#1") is None


def test_reject_reasons_and_start_errors() -> None:
    nan = float("nan")
    assert reject_reason(NavigateThroughPoses(())) == "NavigateThroughPoses needs at least one pose."
    assert reject_reason(NavigateToPose(Pose2D(nan, 0.0))) == "Pose 0 (nan, 0.0, 0.0) is not finite."
    assert reject_reason(FollowWaypoints((Pose2D(1, 1), Pose2D(0, math.inf)))) is not None
    assert reject_reason(FollowWaypoints(())) is None  # accepted, then it fails
    assert start_error(FollowWaypoints(())) == (
        ErrorCode.WAYPOINT_UNKNOWN,
        "FollowWaypoints got an empty list of waypoints.",
    )
    assert start_error(Spin(nan)) == (ErrorCode.SPIN_UNKNOWN, "Spin target nan rad is not a finite angle.")
    assert start_error(BackUp(0.0))[0] == ErrorCode.BACKUP_INVALID_INPUT  # type: ignore[index]
    assert start_error(DriveOnHeading(1.0, speed_mps=nan))[0] == ErrorCode.DRIVE_INVALID_INPUT  # type: ignore[index]
    assert start_error(Wait(1.0)) is None and start_error(NavigateToPose(Pose2D(1, 1))) is None


def test_a_record_finishes_once_and_a_preempted_goal_names_its_successor() -> None:
    book = GoalBook()
    old, new = book.open("/a", Wait(5.0)), book.open("/a", Spin(1.0))
    preempt(old, new, old.feedback)
    old.finish(GoalStatus.SUCCEEDED)  # ignored: already terminal
    state = old.snapshot()
    assert state.status is GoalStatus.ABORTED and state.error_code == 0
    assert state.error_msg == "Goal /a#1 was preempted by goal /a#2."
    assert old.snapshot() is state  # a terminal snapshot is made once
    rejected = book.open("/a", NavigateThroughPoses(()))
    assert reject_if_invalid(rejected) and rejected.snapshot().status is GoalStatus.REJECTED
    assert not reject_if_invalid(new)


def test_simulator_raises_for_a_non_goal_and_keeps_the_running_goal() -> None:
    sim = make_sim({"/r1": Pose2D(2.0, 2.0)})
    gid = sim.send_goal("/r1", Wait(2.0))
    with pytest.raises(BackendError, match="not a navigation goal"):
        sim.send_goal("/r1", NotAGoal())
    advance(sim, 0.5)
    assert sim.goal_state(gid).status is GoalStatus.EXECUTING
    assert sim.send_goal("/r1", Wait(1.0)) == "/r1#2"


def test_the_default_book_stays_bounded_over_a_long_run_of_goals() -> None:
    """A robot on patrol ends about 170 goals an hour: over thousands the book keeps only
    its live goal and the last :data:`KEEP_FINISHED` finished ones per robot."""
    book = GoalBook()
    live = {ns: book.open(ns, Wait(1.0)) for ns in ("/a", "/b")}
    for _ in range(2000):
        for ns in live:
            live[ns].finish(GoalStatus.SUCCEEDED)
            live[ns] = book.open(ns, Wait(1.0))
    assert sum(1 for _ in book.records()) == 2 * (KEEP_FINISHED + 1)
    assert book.live("/a#2001") is live["/a"]
    assert book.get(f"/b#{2001 - KEEP_FINISHED}").status is GoalStatus.SUCCEEDED
