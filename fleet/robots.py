"""Parameters of the simulated robots and world. Plain dataclasses, validated by
``fleet.config`` when they come from a file. Units: meters, radians, seconds; battery levels
are fractions of a full charge in [0, 1]."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from fleet.types import Pose2D


@dataclass(frozen=True)
class RobotModel:
    """Differential-drive limits shared by every robot of a fleet."""

    radius: float = 0.3
    max_linear_speed: float = 1.0
    max_angular_speed: float = 1.5
    max_linear_accel: float = 0.8
    max_angular_accel: float = 3.0


@dataclass(frozen=True)
class BatteryModel:
    """Battery drain and charge. The battery guard sends a robot to charge when its battery
    falls below :meth:`charge_threshold` of its distance to the charger (never below
    ``low``) and the charge leaf releases it at ``resume``.

    The threshold is the energy the trip needs (``drain_per_m`` per meter of
    ``detour`` times the map distance, ``drain_per_s`` over the drive at ``cruise_mps`` and
    ``wait_s`` of waiting for a charger) times ``1 + margin``, plus ``reserve``: a robot far
    from a charger leaves early, one beside it works on."""

    drain_per_m: float = 0.004
    drain_per_s: float = 0.0005
    charge_per_s: float = 0.02
    low: float = 0.1
    resume: float = 0.95
    initial: float = 1.0
    reserve: float = 0.08
    margin: float = 0.5
    wait_s: float = 240.0
    detour: float = 1.2
    cruise_mps: float = 0.6

    def charge_threshold(self, distance_m: float) -> float:
        """The battery fraction below which a robot ``distance_m`` meters (straight or
        Manhattan distance in the map frame) from its charger must go and charge."""
        d = max(0.0, distance_m) * self.detour
        need = self.drain_per_m * d + self.drain_per_s * (d / self.cruise_mps + self.wait_s)
        return max(self.low, self.reserve + (1.0 + self.margin) * need)

    def charge_line(self) -> tuple[float, float]:
        """``(a, b)`` with ``charge_threshold(d) == max(low, a + b * d)`` for ``d >= 0`` (up to
        rounding): the threshold as a line, for checking many robots at once."""
        k = 1.0 + self.margin
        return (
            self.reserve + k * self.drain_per_s * self.wait_s,
            k * self.detour * (self.drain_per_m + self.drain_per_s / self.cruise_mps),
        )

    def integrate(
        self, level: npt.ArrayLike, distance_m: npt.ArrayLike, dt: float, charging: npt.ArrayLike
    ) -> npt.NDArray[np.float64]:
        """The battery level(s) after ``dt`` seconds from ``level`` (fractions in [0, 1]):
        where ``charging``, ``charge_per_s * dt`` more, at most 1; elsewhere ``drain_per_m``
        per meter of ``distance_m`` driven and ``drain_per_s * dt`` less, at least 0.
        Element-wise over arrays (one entry per robot) or on scalars (a 0-d array). Every
        backend integrates its batteries with this one step."""
        level = np.asarray(level, dtype=float)
        charged = np.minimum(1.0, level + self.charge_per_s * dt)
        drained = np.maximum(0.0, level - self.drain_per_m * np.asarray(distance_m) - self.drain_per_s * dt)
        return np.where(charging, charged, drained)


@dataclass(frozen=True)
class RobotSpec:
    """One robot: its name (``robot1``), namespace (``/robot1``), start pose and battery."""

    name: str
    namespace: str
    start: Pose2D
    battery: float = 1.0


@dataclass(frozen=True)
class SimParams:
    """World-level simulation settings.

    ``step_s`` is the fixed step; ``stuck_time_s`` is how long a robot that is trying to move
    may make no progress before it is reported stuck (and its navigation goal aborts with
    ``FAILED_TO_MAKE_PROGRESS``); ``charger_radius`` is how close to a charger pose a robot
    must stand to charge; ``goal_tolerance`` / ``yaw_tolerance`` are Nav2-style goal checker
    tolerances.
    """

    step_s: float = 0.05
    stuck_time_s: float = 8.0
    seed: int = 1
    charger_radius: float = 0.35
    goal_tolerance: float = 0.25
    yaw_tolerance: float = 0.5
    chargers: tuple[Pose2D, ...] = field(default_factory=tuple)
    model: RobotModel = field(default_factory=RobotModel)
    battery: BatteryModel = field(default_factory=BatteryModel)
