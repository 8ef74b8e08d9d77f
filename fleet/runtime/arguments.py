"""Checking the runner's arguments before anything is opened: each error names the field."""

from __future__ import annotations

import math
from collections.abc import Sequence

from fleet.config.model import FleetConfig
from fleet.errors import ConfigError
from fleet.runtime.backends import BACKENDS, backend_names
from fleet.runtime.scheduler import MODES


def check_args(
    config: FleetConfig,
    backend: str,
    speed: float,
    duration: float | None,
    agents: str | Sequence[str],
    ticking: str = "event",
) -> list[str]:
    """Validate the runner's arguments; returns the names of the local agents."""
    if ticking not in MODES:
        raise ConfigError(str(config.path), "ticking", f"must be one of {', '.join(MODES)}, got {ticking!r}")
    if backend not in BACKENDS:
        raise ConfigError(
            str(config.path), "backend", f"unknown backend {backend!r}; known: {', '.join(backend_names())}"
        )
    if speed < 0 or not math.isfinite(speed):
        raise ConfigError(str(config.path), "speed", f"must be >= 0 (0 = as fast as possible), got {speed}")
    if duration is not None and (duration <= 0 or not math.isfinite(duration)):
        raise ConfigError(
            str(config.path), "duration", f"must be a positive number of seconds, got {duration}"
        )
    names = [r.name for r in config.robots]
    if agents == "all":
        return names
    chosen = [agents] if isinstance(agents, str) else list(agents)
    for a in chosen:
        if a not in names:
            raise ConfigError(
                str(config.path), "robots", f"no robot named {a!r} (robots: {', '.join(names)})"
            )
    return chosen


__all__ = ["check_args"]
