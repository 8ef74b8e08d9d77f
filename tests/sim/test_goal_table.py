"""The simulator's batch tables agree with its per-goal and per-robot snapshots."""

from __future__ import annotations

import math

import numpy as np

from fleet.types import (
    BackUp,
    ComputePathToPose,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
)
from sim.goals import STATUS_CODES, TERMINAL, UNKNOWN_CODE
from sim.simulator import Simulator
from tests.sim.sim_testworld import make_sim


def _check(sim: Simulator, ids: dict[str, str]) -> None:
    """The tables say what ``goal_state`` / ``robot_state`` say, robot by robot."""
    table = sim.goal_table()
    robots = sim.robot_table()
    for i, ns in enumerate(sim.namespaces):
        gid = ids.get(ns)
        if gid is None:
            assert table.number[i] == 0 and table.status[i] == -1
            continue
        assert f"{ns}#{table.number[i]}" == gid
        status = sim.goal_state(gid).status
        assert STATUS_CODES[table.status[i]] is status
        assert bool(TERMINAL[table.status[i]]) == status.terminal
        st = sim.robot_state(ns)
        assert (robots.x[i], robots.y[i], robots.theta[i]) == (st.pose.x, st.pose.y, st.pose.theta)
        assert (robots.v[i], robots.w[i], robots.battery[i]) == (
            st.linear_velocity,
            st.angular_velocity,
            st.battery,
        )
        assert (robots.distance_m[i], bool(robots.stuck[i]), bool(robots.charging[i])) == (
            st.distance_m,
            st.stuck,
            st.charging,
        )
    codes = sim._dispatch.goals.status_codes([*ids.values(), "/nobody#1"])
    assert [STATUS_CODES[c] for c in codes[:-1]] == [sim.goal_state(g).status for g in ids.values()]
    assert codes[-1] == UNKNOWN_CODE


def test_goal_table_follows_every_kind_of_goal_end() -> None:
    """Succeeded, preempted, canceled, rejected and aborted goals, behaviors and a planning
    goal beside a motion goal: after every step the tables agree with the snapshots."""
    starts = {f"/r{k}": Pose2D(1.0 + k, 6.5, 0.0) for k in range(6)}
    sim = make_sim(starts)
    ids: dict[str, str] = {}
    _check(sim, ids)
    ids["/r0"] = sim.send_goal("/r0", NavigateToPose(Pose2D(1.0, 2.5, 0.0)))
    ids["/r1"] = sim.send_goal("/r1", NavigateToPose(Pose2D(9.0, 2.0, 0.0)))
    ids["/r2"] = sim.send_goal("/r2", NavigateThroughPoses(()))  # rejected
    ids["/r3"] = sim.send_goal("/r3", Spin(math.pi / 2))
    ids["/r4"] = sim.send_goal("/r4", BackUp(0.3, 0.1))
    ids["/r5"] = sim.send_goal("/r5", Wait(1.0))
    sim.send_goal("/r5", ComputePathToPose(Pose2D(2.0, 2.0, 0.0)))  # beside the Wait: not in the table
    _check(sim, ids)
    for k in range(400):
        if k == 10:
            ids["/r1"] = sim.send_goal("/r1", NavigateToPose(Pose2D(9.0, 3.0, 0.0)))  # preempts
        if k == 20:
            sim.cancel_goal(ids["/r1"])
        if k == 30:
            ids["/r4"] = sim.send_goal("/r4", NavigateToPose(Pose2D(float("nan"), 1.0, 0.0)))
        sim.step()
        _check(sim, ids)
    table = sim.goal_table()
    assert STATUS_CODES[table.status[0]] is GoalStatus.SUCCEEDED
    assert STATUS_CODES[table.status[1]] is GoalStatus.CANCELED
    assert STATUS_CODES[table.status[2]] is GoalStatus.REJECTED
    assert table.number.tolist() == [1, 2, 1, 1, 2, 1]
    assert TERMINAL[table.status].all()
    assert not TERMINAL[UNKNOWN_CODE]


def test_tables_are_copies() -> None:
    sim = make_sim({"/a": Pose2D(1.0, 6.5, 0.0)})
    gid = sim.send_goal("/a", NavigateToPose(Pose2D(3.0, 6.5, 0.0)))
    before = sim.goal_table()
    robots = sim.robot_table()
    sim.run_until(lambda: sim.goal_state(gid).status.terminal, 60.0)
    assert STATUS_CODES[before.status[0]] is GoalStatus.EXECUTING
    assert robots.x[0] == 1.0
    assert np.array_equal(sim.goal_table().number, [1])
