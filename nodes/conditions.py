"""Condition leaves: instant checks that return SUCCESS (true) or FAILURE (false), never
RUNNING. They send no goals, so there is nothing to cancel."""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from py_trees.common import Status

from fleet.navigation import NavigationBackend
from fleet.types import Pose2D
from fleet.wake import wake_of
from nodes.blackboard import robot_blackboard
from nodes.leaves import Source, resolve


class BatteryLow(py_trees.behaviour.Behaviour):
    """True when the robot must go and charge, with hysteresis.

    SUCCESS when the battery is below ``low`` (or, given ``threshold``, below what it
    returns at this tick, e.g. the energy to reach the charger from here); once that happened it stays SUCCESS (latched)
    until the battery is back at or above ``resume`` (charging, typically), so the battery
    guard is not released half-way through a charge. FAILURE otherwise (and when the
    backend reports no state). Fractions in [0, 1].

    A charge under way when the guard first sees its robot (the robot localized, standing on
    a charger and charging below ``resume``: the agent was restarted mid-charge) latches it
    too, so a restarted agent finishes the charge instead of taking work half charged.
    """

    def __init__(
        self,
        backend: NavigationBackend,
        low: float,
        resume: float,
        *,
        threshold: Callable[[], float] | None = None,
        name: str = "BatteryLow",
    ) -> None:
        super().__init__(name=name)
        if not 0.0 <= low <= resume <= 1.0:
            raise ValueError(f"BatteryLow needs 0 <= low <= resume <= 1, got low={low}, resume={resume}")
        self.backend = backend
        self.low = low
        self.resume = resume
        self.threshold = threshold
        #: True between falling below ``low`` and reaching ``resume``.
        self.latched = False
        #: Whether the guard has seen a state of its localized robot yet.
        self.seen = False

    wake_aware = True

    def update(self) -> Status:
        state = self.backend.robot_state()
        battery = state.battery
        low = self.low if self.threshold is None else min(self.resume, self.threshold())
        if not self.seen and state.pose is not None:
            self.seen = True
            self.latched = state.charging and battery < self.resume  # a charge under way goes on
        if battery < low:
            self.latched = True
        elif battery >= self.resume:
            self.latched = False
        self.feedback_message = f"battery {battery:.2f} ({'low' if self.latched else 'ok'})"
        self._declare()
        return Status.SUCCESS if self.latched else Status.FAILURE

    def _declare(self) -> None:
        """What changes this condition's answer (:mod:`fleet.wake`)."""
        wake = wake_of(self.backend)
        if wake is None:
            return
        if self.latched:
            wake.battery_at_least(self.resume)
            return
        declare = getattr(self.threshold, "declare", None)
        if self.threshold is None:
            wake.battery_below(self.low)
        elif callable(declare):
            declare(wake, self.resume)
        else:
            wake.every_tick()  # a threshold that cannot say when it changes


class IsStuck(py_trees.behaviour.Behaviour):
    """SUCCESS when the backend reports the robot stuck (``robot_state().stuck``)."""

    def __init__(self, backend: NavigationBackend, *, name: str = "IsStuck") -> None:
        super().__init__(name=name)
        self.backend = backend

    def update(self) -> Status:
        return Status.SUCCESS if self.backend.robot_state().stuck else Status.FAILURE

    wake_aware = True  # reads a flag the scheduler watches


class IsLocalized(py_trees.behaviour.Behaviour):
    """SUCCESS while the robot is localized: its pose is known, its localizer says it has
    converged (``robot_state().localized``) and the estimate is fresh (``pose_age_s``, the age
    of the last localization update in simulated seconds, at most ``timeout_s``); FAILURE
    otherwise (lost, never localized, or stale)."""

    def __init__(
        self, backend: NavigationBackend, *, timeout_s: float = 5.0, name: str = "IsLocalized"
    ) -> None:
        super().__init__(name=name)
        self.backend = backend
        self.timeout_s = timeout_s

    def update(self) -> Status:
        st = self.backend.robot_state()
        ok = st.pose is not None and st.localized and st.pose_age_s <= self.timeout_s
        return Status.SUCCESS if ok else Status.FAILURE


class NearPose(py_trees.behaviour.Behaviour):
    """SUCCESS when the robot is within ``tolerance_m`` meters (planar distance, heading
    ignored) of ``pose``, given statically or by a callable evaluated at every tick (e.g.
    ``read_key(ns, "charger")``). FAILURE when it is farther, the pose is ``None`` or the
    robot is not localized."""

    def __init__(
        self,
        backend: NavigationBackend,
        pose: Source[Pose2D],
        tolerance_m: float = 0.3,
        *,
        name: str = "NearPose",
    ) -> None:
        super().__init__(name=name)
        self.backend = backend
        self._pose = pose
        self.tolerance_m = tolerance_m

    def update(self) -> Status:
        target = resolve(self._pose)
        here = self.backend.robot_state().pose
        if target is None or here is None:
            self.feedback_message = "no target pose" if target is None else "not localized"
            return Status.FAILURE
        d = here.distance_to(target)
        self.feedback_message = f"{d:.2f} m from the target"
        return Status.SUCCESS if d <= self.tolerance_m else Status.FAILURE


class HasAssignment(py_trees.behaviour.Behaviour):
    """SUCCESS when the robot's blackboard ``key`` (``"route"`` or ``"pick"``) holds an
    assignment: not ``None`` and, for a sequence such as a route, not empty."""

    def __init__(self, namespace: str, key: str = "route", *, name: str | None = None) -> None:
        super().__init__(name=name or f"Has{key.capitalize()}")
        self.key = key
        self.blackboard = robot_blackboard(namespace, name=self.name, keys=(key,))
        self.blackboards.append(self.blackboard)

    wake_aware = True  # reads the blackboard only

    def update(self) -> Status:
        value = self.blackboard.get(self.key)
        if value is None:
            return Status.FAILURE
        if isinstance(value, (tuple, list)) and not value:
            return Status.FAILURE
        return Status.SUCCESS
