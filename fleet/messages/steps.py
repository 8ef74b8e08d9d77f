"""The steps of a task as a robot executes them: drive somewhere, then act there.

A go_to, pick, inspection or park order (:class:`~fleet.messages.TaskMessage` with ``steps``)
is a list of :class:`Step` values that the robot's task tree runs in order
(``nodes/steps.py``). Schemas and examples: ``docs/status_bus.md``.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Final

from msgspec import Struct

from fleet.messages.codec import Finite, Pose, Text
from fleet.types import Pose2D


class Action(StrEnum):
    """What one :class:`Step` does.

    ``drive``: go to ``pose`` (``map`` frame; with traffic management, to the traffic
    roadmap node ``node`` along granted paths); ``wait``: stand ``duration_s`` s (a pick's
    dwell, an inspection wait); ``spin``: turn in place by ``yaw`` rad (signed);
    ``capture``: take the capture called ``name`` where the robot stands (the robot logs it
    and reports it; it takes no time).
    """

    DRIVE = "drive"
    WAIT = "wait"
    SPIN = "spin"
    CAPTURE = "capture"


#: The values of :class:`Action`.
ACTIONS: Final = tuple(a.value for a in Action)


class Step(Struct, frozen=True):
    """One step of a task (see :class:`Action`); ``name`` labels it (a station, a node, a
    capture). Only the fields of its action matter."""

    action: str
    pose: Pose2D | None = None
    node: str | None = None
    duration_s: float = 0.0
    yaw: float = 0.0
    name: str = ""


class StepWire(Struct, frozen=True, kw_only=True, omit_defaults=True):
    """A :class:`Step` on the wire: ``pose`` as ``[x, y, theta]``."""

    action: Text
    pose: Pose | None = None
    node: Text | None = None
    duration_s: Finite = 0.0
    yaw: Finite = 0.0
    name: Text = ""

    def check(self, where: str) -> StepWire:
        """ValueError naming the field for an unknown action, a drive without a pose or a
        negative wait."""
        if self.action not in ACTIONS:
            raise ValueError(f"{where}.action: {self.action!r} is not one of {', '.join(ACTIONS)}")
        if self.action == Action.DRIVE and self.pose is None:
            raise ValueError(f"{where}.pose: a drive step needs a pose")
        if self.duration_s < 0:
            raise ValueError(f"{where}.duration_s: must be >= 0, got {self.duration_s}")
        return self

    def step(self) -> Step:
        return Step(
            action=self.action,
            pose=None if self.pose is None else Pose2D(*self.pose),
            node=self.node,
            duration_s=self.duration_s,
            yaw=self.yaw,
            name=self.name,
        )


def step_wire(s: Step) -> StepWire:
    """The wire form of ``s``."""
    p = s.pose
    return StepWire(
        action=s.action,
        pose=None if p is None else (float(p.x), float(p.y), float(p.theta)),
        node=s.node,
        duration_s=float(s.duration_s),
        yaw=float(s.yaw),
        name=s.name,
    )
