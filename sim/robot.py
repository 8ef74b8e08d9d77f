"""One simulated robot: a view of one row of the simulator's state arrays.

:class:`Robot` names a row of :class:`sim.state.FleetState` (pose in the ``map`` frame,
velocities, battery, odometer, flags) and holds what is not an array: the robot's name,
namespace and its fault. The goal executors running on robots (:mod:`sim.tasks`) are kept by
the dispatcher (:class:`sim.dispatch.GoalDispatch`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleet.types import Pose2D

if TYPE_CHECKING:
    from sim.state import FleetState


class Robot:
    """One simulated differential-drive robot: its identity and fault, and a view of its
    row in the simulator's state arrays (:class:`sim.state.FleetState`).

    Pose ``x``, ``y`` (m) and ``theta`` (rad, in ``[-pi, pi)``) in the ``map`` frame; ``v``
    (m/s, negative = backwards) and ``w`` (rad/s, counter-clockwise positive) are the velocities
    applied during the last step. ``battery`` is a fraction in [0, 1]; ``distance_m`` is the
    odometer (absolute distance driven); ``collisions`` counts contact events this robot took
    part in. ``fault`` is ``None`` or ``"stalled"`` (wheels do not respond). Reading or writing
    an attribute reads or writes the arrays, so tasks see the same state as the vectorized step
    (a write counts as a change of the robot's row: :meth:`sim.state.FleetState.touch`).
    """

    __slots__ = ("name", "namespace", "index", "state", "fault")

    def __init__(self, name: str, namespace: str, index: int, state: FleetState) -> None:
        self.name = name
        self.namespace = namespace
        self.index = index
        self.state = state
        self.fault: str | None = None

    @property
    def pose(self) -> Pose2D:
        s, i = self.state, self.index
        return Pose2D(s.x.item(i), s.y.item(i), s.th.item(i))

    @property
    def x(self) -> float:
        return float(self.state.x.item(self.index))

    @x.setter
    def x(self, value: float) -> None:
        self.state.x[self.index] = value
        self.state.touch(self.index)

    @property
    def y(self) -> float:
        return float(self.state.y.item(self.index))

    @y.setter
    def y(self, value: float) -> None:
        self.state.y[self.index] = value
        self.state.touch(self.index)

    @property
    def theta(self) -> float:
        return float(self.state.th.item(self.index))

    @theta.setter
    def theta(self, value: float) -> None:
        self.state.th[self.index] = value
        self.state.touch(self.index)

    @property
    def v(self) -> float:
        return float(self.state.v.item(self.index))

    @v.setter
    def v(self, value: float) -> None:
        self.state.v[self.index] = value
        self.state.touch(self.index)

    @property
    def w(self) -> float:
        return float(self.state.w.item(self.index))

    @w.setter
    def w(self, value: float) -> None:
        self.state.w[self.index] = value
        self.state.touch(self.index)

    @property
    def battery(self) -> float:
        return float(self.state.battery.item(self.index))

    @battery.setter
    def battery(self, value: float) -> None:
        self.state.battery[self.index] = value
        self.state.touch(self.index)

    @property
    def charging(self) -> bool:
        return bool(self.state.charging.item(self.index))

    @charging.setter
    def charging(self, value: bool) -> None:
        self.state.charging[self.index] = value
        self.state.touch(self.index)

    @property
    def stuck(self) -> bool:
        return bool(self.state.stuck.item(self.index))

    @stuck.setter
    def stuck(self, value: bool) -> None:
        self.state.stuck[self.index] = value
        self.state.touch(self.index)

    @property
    def distance_m(self) -> float:
        return float(self.state.dist.item(self.index))

    @distance_m.setter
    def distance_m(self, value: float) -> None:
        self.state.dist[self.index] = value
        self.state.touch(self.index)

    @property
    def collisions(self) -> int:
        return int(self.state.collisions.item(self.index))

    @collisions.setter
    def collisions(self, value: int) -> None:
        self.state.collisions[self.index] = value
        self.state.touch(self.index)

    @property
    def progress_x(self) -> float:
        return float(self.state.px.item(self.index))

    @progress_x.setter
    def progress_x(self, value: float) -> None:
        self.state.px[self.index] = value
        self.state.touch(self.index)

    @property
    def progress_y(self) -> float:
        return float(self.state.py.item(self.index))

    @progress_y.setter
    def progress_y(self, value: float) -> None:
        self.state.py[self.index] = value
        self.state.touch(self.index)

    @property
    def progress_t(self) -> float:
        return float(self.state.pt.item(self.index))

    @progress_t.setter
    def progress_t(self, value: float) -> None:
        self.state.pt[self.index] = value
        self.state.touch(self.index)
