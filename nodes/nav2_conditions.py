"""Nav2's condition nodes (``nav2_behavior_tree``) as py_trees leaves: SUCCESS = true,
FAILURE = false, never RUNNING, nothing to cancel. Registered under their Nav2 names by
:mod:`nodes.catalog`.

* ``GoalReached``: the robot within ``goal_reached_tol`` (0.25 m) of ``goal``.
* ``GoalUpdated`` / ``GlobalUpdatedGoal``: ``goal`` or ``goals`` changed since the node's last
  tick (``GoalUpdated`` forgets what it saw when halted, ``GlobalUpdatedGoal`` does not).
* ``IsBatteryLow`` (``min_battery``, a fraction), ``IsBatteryCharging``, ``IsStuck``,
  ``TransformAvailable`` (the robot is localized), ``InitialPoseReceived``.
* ``DistanceTraveled``, ``TimeExpired``, ``PathExpiringTimer``: true once the robot moved
  ``distance`` m / ``seconds`` passed (injected clock) since the node last was true (the
  timer restarts when ``path`` changes).
* ``AreErrorCodesPresent`` and ``WouldA{Controller,Planner,Smoother}RecoveryHelp``: the
  ``error_code`` is in ``error_codes_to_check`` (the three ``WouldA*`` nodes default to Nav2's
  lists: controller 100, 104, 105, 106; planner 200, 207, 208, 300, 307, 308; smoother 500,
  502, 503, 504). A key never written reads as 0 (no error).
* ``ArePosesNear``: ``ref_pose`` and ``target_pose`` within ``tolerance``.
"""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from py_trees.common import Status

from fleet.navigation import Clock, NavigationBackend
from fleet.types import ErrorCode
from nodes.ports import Ports

#: Nav2's WouldAControllerRecoveryHelp codes.
CONTROLLER_RECOVERY_CODES = (
    ErrorCode.CONTROLLER_UNKNOWN,
    ErrorCode.PATIENCE_EXCEEDED,
    ErrorCode.FAILED_TO_MAKE_PROGRESS,
    ErrorCode.NO_VALID_CONTROL,
)
#: Nav2's WouldAPlannerRecoveryHelp codes.
PLANNER_RECOVERY_CODES = (
    ErrorCode.PLANNER_UNKNOWN,
    ErrorCode.NO_VALID_PATH,
    ErrorCode.PLANNER_TIMEOUT,
    ErrorCode.THROUGH_POSES_UNKNOWN,
    ErrorCode.THROUGH_POSES_TIMEOUT,
    ErrorCode.THROUGH_POSES_NO_VALID_PATH,
)
#: Nav2's WouldASmootherRecoveryHelp codes.
SMOOTHER_RECOVERY_CODES = (
    ErrorCode.SMOOTHER_UNKNOWN,
    ErrorCode.SMOOTHER_TIMEOUT,
    ErrorCode.FAILED_TO_SMOOTH_PATH,
    ErrorCode.SMOOTHED_PATH_IN_COLLISION,
)


class Check(py_trees.behaviour.Behaviour):
    """A condition: ``test(ports)`` true -> SUCCESS, false -> FAILURE. ``on_halt`` runs when
    the node is halted (``stop(INVALID)``)."""

    def __init__(
        self,
        name: str,
        ports: Ports,
        test: Callable[[Ports], bool],
        on_halt: Callable[[], None] | None = None,
    ) -> None:
        super().__init__(name=name)
        self.ports = ports
        self._test = test
        self._on_halt = on_halt

    def update(self) -> Status:
        return Status.SUCCESS if self._test(self.ports) else Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self._on_halt is not None:
            self._on_halt()


def error_codes_present(defaults: tuple[int, ...]) -> Callable[[Ports], bool]:
    """``error_code`` in ``error_codes_to_check`` (default ``defaults``)."""

    def test(p: Ports) -> bool:
        code = p.get_int("error_code", 0)
        given = p.get("error_codes_to_check")
        codes = tuple(int(c) for c in given) if isinstance(given, tuple) else tuple(int(c) for c in defaults)
        return code in codes

    return test


class ChangeWatch:
    """Whether ``value()`` changed since the last :meth:`changed` (the first call sees no
    change). :meth:`forget` makes the next call start over."""

    def __init__(self, value: Callable[[], object]) -> None:
        self._value = value
        self._seen: object = None
        self._primed = False

    def changed(self) -> bool:
        v = self._value()
        if not self._primed:
            self._primed, self._seen = True, v
            return False
        if v != self._seen:
            self._seen = v
            return True
        return False

    def forget(self) -> None:
        self._primed = False


def goal_updated(name: str, ports: Ports, *, global_: bool) -> Check:
    """``GoalUpdated`` / ``GlobalUpdatedGoal`` (see the module docstring)."""
    watch = ChangeWatch(lambda: (ports.get("goal"), ports.get("goals")))
    return Check(name, ports, lambda _p: watch.changed(), None if global_ else watch.forget)


def goal_reached(backend: NavigationBackend, tolerance: float) -> Callable[[Ports], bool]:
    def test(p: Ports) -> bool:
        goal, here = p.get_pose("goal"), backend.robot_state().pose
        return goal is not None and here is not None and here.distance_to(goal) <= tolerance

    return test


def distance_traveled(name: str, ports: Ports, backend: NavigationBackend) -> Check:
    start: list[tuple[float, float] | None] = [None]

    def test(p: Ports) -> bool:
        here = backend.robot_state().pose
        if here is None:
            return False
        if start[0] is None:
            start[0] = (here.x, here.y)
            return False
        if ((here.x - start[0][0]) ** 2 + (here.y - start[0][1]) ** 2) ** 0.5 >= p.get_float("distance", 1.0):
            start[0] = (here.x, here.y)
            return True
        return False

    return Check(name, ports, test)


def time_expired(name: str, ports: Ports, clock: Clock, *, path_port: str | None = None) -> Check:
    """``TimeExpired`` (and, with ``path_port``, ``PathExpiringTimer``: the timer restarts
    when the path changes)."""
    t0: list[float | None] = [None]
    watch = ChangeWatch(lambda: ports.get(path_port)) if path_port else None

    def test(p: Ports) -> bool:
        now = clock.now()
        if t0[0] is None or (watch is not None and watch.changed()):
            t0[0] = now
            return False
        if now - t0[0] >= p.get_float("seconds", 1.0) - 1e-9:
            t0[0] = now
            return True
        return False

    return Check(name, ports, test)


def battery_low(backend: NavigationBackend) -> Callable[[Ports], bool]:
    return lambda p: backend.robot_state().battery <= p.get_float("min_battery", 0.0)


def poses_near(p: Ports) -> bool:
    a, b = p.get_pose("ref_pose"), p.get_pose("target_pose")
    return a is not None and b is not None and a.distance_to(b) <= p.get_float("tolerance", 0.5)
