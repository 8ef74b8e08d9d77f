"""The per-period path of a robot whose tree does not tick builds its values without the frozen
dataclasses' ``__init__`` and reads its state below pass-through wrappers: the objects must be
the very ones the plain constructors and reads give, and the e-stop latch must still act on a
state read alone."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import pytest
from ports import free_endpoint

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.coordination.coordinator import Coordinator, observation_from_record
from fleet.coordination.views import Observation
from fleet.messages import StatusRecord
from fleet.navigation import state_reader
from fleet.runtime.goal_log import GoalLog
from fleet.runtime.latch import Latch, LatchedBackend
from fleet.runtime.runner import FleetRunner
from fleet.types import GoalStatus, NavigateToPose, Pose2D, RobotState, frozen_factory, make_pose
from fleet.viz.display import NullDisplay
from sim.simulator import Simulator
from sim.snapshots import localized_robot_state

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


def test_an_in_process_coordinator_reads_every_record_as_it_would_from_the_record() -> None:
    """The agents hand the in-process coordinator an Observation built from the state and tree
    they read; over a run with laps and traffic management it is, tick by tick, the Observation
    the coordinator would make of the record."""
    runner = FleetRunner(
        load_config(ROOT / "configs" / "warehouse_patrol.yaml"),
        duration=120.0,
        speed=0,
        endpoint=free_endpoint(),
        live=False,
        display=NullDisplay(),
        out=io.StringIO(),
    )
    pairs: list[tuple[Observation, StatusRecord]] = []
    real = Coordinator.feed_observation

    def feed(coordinator: Coordinator, robot: str, obs: Observation) -> None:
        agent = next(a for a in runner.agents if a.name == robot)
        assert agent.last_status is not None and agent.last_status.robot == robot
        pairs.append((obs, agent.last_status))
        real(coordinator, robot, obs)

    Coordinator.feed_observation = feed  # type: ignore[method-assign]
    try:
        report = runner.run()
    finally:
        Coordinator.feed_observation = real  # type: ignore[method-assign]
    assert report.laps_completed > 0 and len(pairs) >= 6 * 120 * runner.config.tick_hz * 0.9
    assert {o.mode for o, _ in pairs} >= {"patrol"}
    for obs, rec in pairs:
        assert obs == observation_from_record(rec), rec.robot


def test_a_localized_robot_state_is_the_dataclass_state() -> None:
    pose = Pose2D(1.0, 2.0, 0.5)
    fast = localized_robot_state(pose, 0.4, -0.1, 0.8, True, False, 12.5, 2, False, "bumper")
    plain = RobotState(
        pose=pose, linear_velocity=0.4, angular_velocity=-0.1, battery=0.8, charging=True, stuck=False,
        distance_m=12.5, collisions=2, navigation_ready=False, safety_stop="bumper",
    )  # fmt: skip
    assert fast == plain and type(fast) is RobotState
    assert list(vars(fast).items()) == list(
        vars(plain).items()
    )  # localized, pose age, battery known: defaults
