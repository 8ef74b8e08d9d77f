"""Robot diagnostics and the safety watchdog: what is wrong with a robot, how badly, and when
it must be stopped.

Every robot is checked under five names (the ``name`` of each :class:`Diagnostic`), each at one
:class:`Level` (the levels of ROS's ``diagnostic_msgs/DiagnosticStatus``):

* ``battery``: OK; WARN below ``battery_low`` (the robot should charge) or when no battery
  sensor reports (the level is an assumption); ERROR at or below ``battery_critical``;
* ``localization``: OK while the pose estimate is converged and fresh; WARN when it is older
  than half ``localization_timeout_s``; ERROR when it is not localized or older than
  ``localization_timeout_s`` (what ``IsLocalized`` calls lost);
* ``motion``: OK; WARN while the robot is stuck (no progress while trying to move);
  ERROR while the safety watchdog holds it stopped;
* ``navigation``: OK while the robot's navigation server is up and active; ERROR otherwise;
* ``bus``: the robot's link to the fleet, judged by whoever receives its statuses: OK while
  they arrive, STALE when the last one is older than ``stale_after_s`` (:func:`stale`).

:func:`robot_diagnostics` computes them from a :class:`~fleet.types.RobotState`; the agent
puts the worst level and the items that are not OK in its status record (``health``,
``diag``), ``fleet status`` shows them, and ``fleet sim-ros`` publishes them on
``/diagnostics``.

:class:`SafetyWatchdog` is the fleet-side safety stop: checked once per agent tick (one control
period), it trips when the robot's localization is lost or stale or its navigation server is
down (or the robot's own watchdog stopped it), and clears when all is well again. Core module:
imports nothing but :mod:`fleet.types`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from fleet.types import RobotState

#: The names checked, in display order.
NAMES = ("battery", "localization", "motion", "navigation", "bus")


class Level(enum.IntEnum):
    """Severity, as ``diagnostic_msgs/DiagnosticStatus`` (OK 0, WARN 1, ERROR 2, STALE 3)."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class Diagnostic:
    """One check of one robot: ``name`` (see :data:`NAMES`), ``level``, a sentence
    ``message`` and ``values`` (key, value text) for detail."""

    name: str
    level: Level
    message: str
    values: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class HealthParams:
    """Thresholds of the checks (fractions of a full battery; simulated seconds)."""

    battery_low: float = 0.25
    battery_critical: float = 0.05
    localization_timeout_s: float = 5.0
    stale_after_s: float = 5.0


def robot_diagnostics(state: RobotState, params: HealthParams = HealthParams()) -> tuple[Diagnostic, ...]:
    """The checks of :data:`NAMES` but ``bus`` (judged by the receiver) for ``state``."""
    return (
        _battery(state, params),
        _localization(state, params),
        _motion(state),
        _navigation(state),
    )


def _battery(st: RobotState, p: HealthParams) -> Diagnostic:
    pct = f"{100.0 * st.battery:.0f} %"
    values = (("percentage", f"{st.battery:.3f}"), ("charging", str(st.charging).lower()))
    if not st.battery_known:
        return Diagnostic(
            "battery", Level.WARN, "no battery state published: the level is unknown (assumed full)", values
        )
    if st.battery <= p.battery_critical:
        return Diagnostic("battery", Level.ERROR, f"battery critical: {pct}", values)
    if st.battery < p.battery_low:
        return Diagnostic(
            "battery", Level.WARN, f"battery low: {pct}" + (" (charging)" if st.charging else ""), values
        )
    return Diagnostic("battery", Level.OK, f"{pct}" + (" (charging)" if st.charging else ""), values)


def _localization(st: RobotState, p: HealthParams) -> Diagnostic:
    values = (("pose_age_s", f"{st.pose_age_s:.2f}"),)
    if st.pose is None:
        return Diagnostic("localization", Level.ERROR, "no pose estimate", values)
    if not st.localized:
        return Diagnostic("localization", Level.ERROR, "not localized", values)
    if st.pose_age_s > p.localization_timeout_s:
        return Diagnostic(
            "localization", Level.ERROR, f"pose estimate {st.pose_age_s:.1f} s old: localization lost", values
        )
    if st.pose_age_s > 0.5 * p.localization_timeout_s:
        return Diagnostic("localization", Level.WARN, f"pose estimate {st.pose_age_s:.1f} s old", values)
    return Diagnostic("localization", Level.OK, "localized", values)


def _motion(st: RobotState) -> Diagnostic:
    if st.safety_stop:
        return Diagnostic("motion", Level.ERROR, f"safety stop: {st.safety_stop}")
    if st.stuck:
        return Diagnostic("motion", Level.WARN, "stuck: no progress while trying to move")
    return Diagnostic("motion", Level.OK, "moving freely" if abs(st.linear_velocity) > 1e-3 else "standing")


def _navigation(st: RobotState) -> Diagnostic:
    if not st.navigation_ready:
        return Diagnostic("navigation", Level.ERROR, "navigation server down or not active")
    return Diagnostic("navigation", Level.OK, "navigation server active")


def stale(age_s: float | None, params: HealthParams = HealthParams()) -> Diagnostic:
    """The ``bus`` check of a robot whose last status is ``age_s`` simulated seconds old
    (``None``: never heard of)."""
    if age_s is None:
        return Diagnostic("bus", Level.STALE, "no status received")
    if age_s > params.stale_after_s:
        return Diagnostic("bus", Level.STALE, f"no status for {age_s:.1f} s")
    return Diagnostic("bus", Level.OK, "statuses arriving")


def worst(items: tuple[Diagnostic, ...] | list[Diagnostic]) -> Level:
    """The highest level of ``items`` (OK when empty)."""
    return max((d.level for d in items), default=Level.OK)


def problems(items: tuple[Diagnostic, ...] | list[Diagnostic]) -> tuple[tuple[str, int, str], ...]:
    """The items that are not OK as ``(name, level, message)`` (the status record's ``diag``)."""
    return tuple((d.name, int(d.level), d.message) for d in items if d.level != Level.OK)


def watchdog_reason(state: RobotState, params: HealthParams = HealthParams()) -> str:
    """Why the robot in ``state`` must be stopped now (``""``: it need not)."""
    if state.safety_stop:
        return state.safety_stop
    if not state.navigation_ready:
        return "navigation server down"
    if state.pose is None or not state.localized:
        return "localization lost"
    if state.pose_age_s > params.localization_timeout_s:
        return f"localization lost: pose estimate {state.pose_age_s:.1f} s old"
    return ""


class SafetyWatchdog:
    """The fleet-side safety stop of one robot (see the module docstring). :meth:`check`
    returns the reason the robot must stand still now (``""``: it may drive) and counts the
    stops (``trips``; ``reason`` the current one)."""

    def __init__(self, params: HealthParams = HealthParams()) -> None:
        self.params = params
        self.reason = ""
        self.trips = 0

    def check(self, state: RobotState) -> str:
        reason = watchdog_reason(state, self.params)
        if reason and not self.reason:
            self.trips += 1
        self.reason = reason
        return reason
