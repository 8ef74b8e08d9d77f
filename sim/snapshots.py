"""Fast constructors of the frozen snapshot types polled every tick (goal state, feedback,
robot state)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TypeVar

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
