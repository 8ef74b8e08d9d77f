"""The per-period path of a robot whose tree does not tick builds its values without the frozen
dataclasses' ``__init__`` and reads its state below pass-through wrappers: the objects must be
the very ones the plain constructors and reads give, and the e-stop latch must still act on a
state read alone."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.coordination.coordinator import observation_from_record
from fleet.coordination.views import Observation
from fleet.messages import StatusRecord
from fleet.navigation import state_reader
from fleet.runtime.goal_log import GoalLog
from fleet.runtime.latch import Latch, LatchedBackend
from fleet.types import GoalStatus, NavigateToPose, Pose2D, frozen_factory, make_pose
from sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[3]


def test_make_pose_is_the_pose_the_dataclass_builds() -> None:
    fast, plain = make_pose(1.5, -2.0, 0.25), Pose2D(1.5, -2.0, 0.25)
    assert fast == plain and hash(fast) == hash(plain) and type(fast) is Pose2D
    assert list(vars(fast).items()) == list(vars(plain).items())  # same fields, same order
    assert make_pose(3.0, 4.0) == Pose2D(3.0, 4.0)  # theta defaults to 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.x = 0.0  # type: ignore[misc]  # still frozen
    assert dataclasses.replace(fast, theta=1.0) == Pose2D(1.5, -2.0, 1.0)


@pytest.mark.parametrize("pose", [(2.0, 3.0, 0.5), None])
def test_observation_from_record_is_the_dataclass_observation(
    pose: tuple[float, float, float] | None,
) -> None:
    rec = StatusRecord(
        robot="robot7", ns="/robot7", t=12.5, pose=pose, battery=0.4, charging=False, stuck=True,
        bt="RUNNING", leaf="Drive", mode="patrol", task_id="p3", laps=2, progress=0.3, distance_m=8.0,
        collisions=0, seq=9, picks_done=1, result_id="r1", result="done", steps_done=3,
    )  # fmt: skip
    obs = observation_from_record(rec)
    plain = Observation(
        t=12.5, pose=None if pose is None else Pose2D(*pose), battery=0.4, mode="patrol", stuck=True,
        task_id="p3", laps=2, picks_done=1, result_id="r1", result="done", steps_done=3,
    )  # fmt: skip
    assert obs == plain and type(obs) is Observation
    assert list(vars(obs).items()) == list(vars(plain).items())
    assert frozen_factory(Observation)(t=1.0, pose=None) == Observation(t=1.0, pose=None)  # defaults filled


def test_state_read_below_the_wrappers_is_the_robot_state_and_the_latch_still_cancels() -> None:
    cfg = load_config(ROOT / "configs" / "warehouse_patrol.yaml", robots=1)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    spec = cfg.robots[0]
    sim.add_robot(spec)
    latch = Latch()
    backend = LatchedBackend(GoalLog(sim.backend(spec.namespace), sim.clock, 1.0), latch)
    gid = backend.send_goal(NavigateToPose(Pose2D(2.5, 14.0, 1.57)))
    for _ in range(20):
        sim.step()
    assert state_reader(backend)() == backend.robot_state() == sim.robot_state(spec.namespace)
    moving = backend.robot_state()
    assert moving.linear_velocity != 0 or moving.angular_velocity != 0  # a robot on its way
    latch.set(True)
    backend.robot_state()  # a state read alone applies the latch: the goal it let through ends
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
