"""The shipped warehouse's robot start poses, for tests that give a robot its initial pose as
nav2_simple_commander's examples do (the pose the config starts it at, yaw included)."""

from __future__ import annotations

from functools import cache
from pathlib import Path

from fleet.config.loader import load_config
from fleet.types import Pose2D

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


@cache
def start_pose(namespace: str, config: Path = WAREHOUSE) -> Pose2D:
    """Where robot ``namespace`` (``/robot1`` or ``robot1``) starts in ``config``."""
    name = namespace.strip("/")
    for r in load_config(config).robots:
        if r.name == name:
            return r.start
    raise KeyError(f"{config}: no robot {name!r}")
