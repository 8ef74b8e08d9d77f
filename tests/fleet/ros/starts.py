"""The shipped warehouse's robot start poses, for tests that give a robot its initial pose as
nav2_simple_commander's examples do (the pose the config starts it at, yaw included)."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

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


class LocalizedCommanders(dict):  # type: ignore[type-arg]
    """``{namespace: Commander}`` made on first use, each given its robot's pose as
    nav2_simple_commander's examples do (the default initial pose, (0, 0), would leave the
    robot mislocalized and stopped): the config's start the first time a robot is met in
    ``given`` (one set per server), else its current estimate (where the last test left it)."""

    def __init__(self, context: Any, given: set[str]) -> None:
        super().__init__()
        self.context = context
        self.given = given

    def __missing__(self, ns: str) -> Any:
        from commander import Commander

        from fleet.ros.conversions import pose2d_to_pose_stamped

        nav = Commander(ns, self.context)
        if ns not in self.given:
            self.given.add(ns)
            nav.setInitialPose(pose2d_to_pose_stamped(start_pose(ns)))
        else:
            nav.setInitialPose(nav.current_estimate())
        self[ns] = nav
        return nav

    def close(self) -> None:
        for nav in self.values():
            nav.close()
