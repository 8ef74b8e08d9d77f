"""Fast constructors of the frozen snapshot types polled every tick (goal state, feedback,
robot state), and the batch tables (:class:`GoalTable`, :class:`RobotTable`) that poll a
whole fleet as arrays without building one object per robot."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from fleet.types import Feedback, GoalState, RobotState

_T = TypeVar("_T")


def frozen_factory(cls: type[_T]) -> Callable[..., _T]:
    """A keyword-only constructor of the dataclass ``cls`` that builds the very instance
    ``cls(**fields)`` would (same class, same attribute dict in field order) without the
    generated ``__init__``, whose one ``object.__setattr__`` per field of a frozen dataclass
    is most of the cost of the goal and robot snapshots polled every tick (about 1 µs each).
    Every field without a default must be passed. For anything but a plain dataclass (slots,
    ``__post_init__``, default factories, fields outside ``__init__``) it returns ``cls``."""
    fields = dataclasses.fields(cls) if dataclasses.is_dataclass(cls) else ()
    plain = (
        bool(fields)
        and "__slots__" not in vars(cls)
        and not hasattr(cls, "__post_init__")
        and all(f.init and f.default_factory is dataclasses.MISSING for f in fields)
    )
    if not plain:
        return cls
    template = {f.name: None if f.default is dataclasses.MISSING else f.default for f in fields}
    new = object.__new__

    def make(**values: object) -> _T:
        obj = new(cls)
        state = obj.__dict__
        state.update(template)
        state.update(values)
        return obj

    return make


#: Fast constructors of the snapshot types (see :func:`frozen_factory`).
make_feedback = frozen_factory(Feedback)
make_goal_state = frozen_factory(GoalState)
make_robot_state = frozen_factory(RobotState)


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
