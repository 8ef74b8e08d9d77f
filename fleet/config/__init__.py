"""Fleet configuration files: :func:`load_config` reads and validates one YAML file
(format: ``docs/config.md``) into a :class:`FleetConfig`."""

from fleet.config.loader import load_config
from fleet.config.model import CoordinatorParams, FleetConfig, NamedPose, PickTask, Route, TrafficSettings

__all__ = [
    "CoordinatorParams",
    "FleetConfig",
    "NamedPose",
    "PickTask",
    "Route",
    "TrafficSettings",
    "load_config",
]
