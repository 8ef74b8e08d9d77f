"""Fast constructors of the frozen snapshot types polled every tick (goal state, feedback,
robot state), and the batch tables (:class:`GoalTable`, :class:`RobotTable`) that poll a
whole fleet as arrays without building one object per robot."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fleet.types import Feedback, GoalState, Pose2D, RobotState, frozen_factory

#: Fast constructors of the snapshot types (see :func:`frozen_factory`).
make_feedback = frozen_factory(Feedback)
make_goal_state = frozen_factory(GoalState)
make_robot_state = frozen_factory(RobotState)

_STATE_DEFAULTS = {
    f.name: None if f.default is dataclasses.MISSING else f.default for f in dataclasses.fields(RobotState)
}
_new = object.__new__


def localized_robot_state(
    pose: Pose2D,
    linear_velocity: float,
    angular_velocity: float,
    battery: float,
    charging: bool,
    stuck: bool,
    distance_m: float,
    collisions: int,
    navigation_ready: bool,
    safety_stop: str,
) -> RobotState:
    """``RobotState(pose=pose, ..., safety_stop=safety_stop)`` of a localized robot (the other
    fields at their defaults), built as :func:`frozen_factory` builds it but from positional
    arguments: about half the cost of the keyword call, for the state read of every robot
    every period."""
    obj = _new(RobotState)
    state = obj.__dict__
    state.update(_STATE_DEFAULTS)
    state["pose"] = pose
    state["linear_velocity"] = linear_velocity
    state["angular_velocity"] = angular_velocity
    state["battery"] = battery
    state["charging"] = charging
    state["stuck"] = stuck
    state["distance_m"] = distance_m
    state["collisions"] = collisions
    state["navigation_ready"] = navigation_ready
    state["safety_stop"] = safety_stop
    return obj


@dataclass(frozen=True)
class GoalTable:
    """The latest motion goal of every robot, as arrays in the simulator's robot order
    (``Simulator.namespaces``), copied out at one instant (between steps).

    ``number[i]`` (int64) is the ``n`` of the robot's goal id ``"<namespace>#<n>"`` (0: it
    never got a motion goal); ``status[i]`` (int8) is that goal's status as a code of
    :data:`sim.goals.STATUS_CODES` (-1: no goal); :data:`sim.goals.TERMINAL` indexed by the
    codes tells which ended. Computation goals (planning, smoothing) are not in the table."""

    number: np.ndarray
    status: np.ndarray


@dataclass(frozen=True)
class RobotTable:
    """Every robot's true state as arrays in the simulator's robot order, copied out at one
    instant: ``x``, ``y`` (m, ``map``), ``theta`` (rad), ``v`` (m/s), ``w`` (rad/s),
    ``battery`` (0..1), ``distance_m`` (odometer, m), ``charging``, ``stuck`` (bool),
    ``collisions`` (int64). The true pose: a robot that is not localized reports its estimate
    through ``Simulator.robot_state`` instead."""

    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray
    v: np.ndarray
    w: np.ndarray
    battery: np.ndarray
    distance_m: np.ndarray
    charging: np.ndarray
    stuck: np.ndarray
    collisions: np.ndarray
