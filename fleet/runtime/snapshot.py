"""The simulator's snapshot: where ``fleet sim --state DIR`` keeps the simulated time and every
robot's pose and battery, so that a ``fleet sim`` killed (even ``kill -9``) and started again
with the same ``--state`` puts its robots back where they were instead of at the config's
start poses, and its clock near the time the fleet had reached.

The file is ``DIR/sim.json`` (:data:`SNAPSHOT_FILE`), written atomically (a temporary file
renamed over it) every :data:`SNAPSHOT_EVERY_S` wall seconds and at the end of a run::

    {"version": 1, "fleet": "warehouse_patrol", "t": 152.35,
     "robots": {"robot1": {"x": 3.2, "y": 7.5, "theta": 1.57, "battery": 0.81}, ...}}

What a restarted simulator does not get back: the robots' goals (the agents send new ones), the
odometers (``distance_m`` starts at 0 again), the collision counts and the trajectories drawn
before the restart. Robots of the config missing from the snapshot, or whose saved pose is no
longer free, start at their configured start pose.
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.errors import ConfigError
from fleet.robots import RobotSpec
from fleet.types import Pose2D

if TYPE_CHECKING:
    from sim.simulator import Simulator

logger = logging.getLogger(__name__)

#: The snapshot's file name inside the ``--state`` directory.
SNAPSHOT_FILE = "sim.json"
#: Wall seconds between two snapshots of a running ``fleet sim``.
SNAPSHOT_EVERY_S = 0.5
_VERSION = 1


@dataclass(frozen=True)
class RobotSnapshot:
    """One robot: pose in the ``map`` frame (m, m, rad) and battery (fraction of full)."""

    pose: Pose2D
    battery: float


@dataclass(frozen=True)
class SimSnapshot:
    """The simulated time ``t`` (s) and the robots (by name) of one fleet ``fleet``."""

    fleet: str
    t: float
    robots: dict[str, RobotSnapshot] = field(default_factory=dict)

    def to_json(self) -> str:
        robots = {
            n: {"x": r.pose.x, "y": r.pose.y, "theta": r.pose.theta, "battery": r.battery}
            for n, r in self.robots.items()
        }
        return json.dumps({"version": _VERSION, "fleet": self.fleet, "t": self.t, "robots": robots})

    def respec(self, spec: RobotSpec) -> RobotSpec:
        """``spec`` starting at this snapshot's pose and battery (as is if it has none)."""
        r = self.robots.get(spec.name)
        return spec if r is None else replace(spec, start=r.pose, battery=r.battery)


def take(sim: Simulator, fleet: str, names: dict[str, str]) -> SimSnapshot:
    """The snapshot of ``sim`` now; ``names`` maps each robot's namespace to its name."""
    robots: dict[str, RobotSnapshot] = {}
    for ns, name in names.items():
        st = sim.robot_state(ns)
        if st.pose is not None:
            robots[name] = RobotSnapshot(st.pose, float(st.battery))
    return SimSnapshot(fleet, float(sim.clock.now()), robots)


def write(path: Path, snap: SimSnapshot) -> None:
    """Write ``snap`` to ``path`` atomically (a reader never sees half a file)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(snap.to_json())
    os.replace(tmp, path)


def read(path: Path, fleet: str) -> SimSnapshot | None:
    """The snapshot at ``path`` (``None`` if there is none). Raises
    :class:`~fleet.errors.ConfigError` naming the file and the field for a file that is not a
    snapshot of the fleet ``fleet``."""
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ConfigError(str(path), "", f"not a simulator snapshot: {e}") from None
    if not isinstance(doc, dict) or doc.get("version") != _VERSION:
        raise ConfigError(str(path), "version", f"expected a version {_VERSION} simulator snapshot")
    if doc.get("fleet") != fleet:
        raise ConfigError(
            str(path),
            "fleet",
            f"the snapshot is of fleet {doc.get('fleet')!r}, not {fleet!r}: use another --state",
        )
    t = _number(doc.get("t"), path, "t")
    robots: dict[str, RobotSnapshot] = {}
    raw = doc.get("robots")
    if not isinstance(raw, dict):
        raise ConfigError(str(path), "robots", "must be a mapping of robot name to pose and battery")
    for name, r in raw.items():
        where = f"robots.{name}"
        if not isinstance(r, dict):
            raise ConfigError(str(path), where, "must be a mapping with x, y, theta, battery")
        pose = Pose2D(*(_number(r.get(k), path, f"{where}.{k}") for k in ("x", "y", "theta")))
        battery = min(1.0, max(0.0, _number(r.get("battery"), path, f"{where}.battery")))
        robots[str(name)] = RobotSnapshot(pose, battery)
    return SimSnapshot(fleet, t, robots)


def _number(v: Any, path: Path, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(str(path), where, f"must be a finite number, got {v!r}")
    return float(v)
