"""The simulator's snapshot: where ``fleet sim --state DIR`` and ``fleet run --state DIR`` keep
the simulated time and every robot's pose, battery and docking state, so that a process killed
(even ``kill -9``) and started again with the same ``--state`` puts its robots back where they
were instead of at the config's start poses, and its clock near the time the fleet had reached.

The file is ``DIR/sim.json`` (:data:`SNAPSHOT_FILE`), one entry per robot (its size is bounded
by the fleet's), written atomically (a temporary file renamed over it: a reader, or a process
started after a kill, never sees half a file) every :data:`SNAPSHOT_EVERY_S` wall seconds and
at the end of a run (:class:`SnapshotWriter`)::

    {"version": 1, "fleet": "warehouse_patrol", "t": 152.35,
     "robots": {"robot1": {"x": 3.2, "y": 7.5, "theta": 1.57, "battery": 0.81, "charging": true}, ...}}

``charging`` (docked on a charger and charging; optional, default false) is restored before the
simulator's first step, so an agent started with the resumed simulator sees the charge under
way at its first look and finishes it (``nodes.conditions.BatteryLow``). What a resumed
simulator does not get back: the robots' goals (the agents send new ones), the odometers
(``distance_m`` starts at 0 again), the collision counts and the trajectories drawn before the
restart. Robots of the config missing from the snapshot, or whose saved pose is no longer free,
start at their configured start pose. A kill loses at most the last :data:`SNAPSHOT_EVERY_S`
wall seconds of motion (the file is not fsynced: it survives the process, not a power cut).
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.errors import BackendError, ConfigError
from fleet.robots import RobotSpec
from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from sim.simulator import Simulator

logger = logging.getLogger(__name__)

#: The snapshot's file name inside the ``--state`` directory.
SNAPSHOT_FILE = "sim.json"
#: Wall seconds between two snapshots of a running simulator.
SNAPSHOT_EVERY_S = 0.5
_VERSION = 1


@dataclass(frozen=True)
class RobotSnapshot:
    """One robot: pose in the ``map`` frame (m, m, rad), battery (fraction of full) and whether
    it was docked on a charger, charging."""

    pose: Pose2D
    battery: float
    charging: bool = False


@dataclass(frozen=True)
class SimSnapshot:
    """The simulated time ``t`` (s) and the robots (by name) of one fleet ``fleet``."""

    fleet: str
    t: float
    robots: dict[str, RobotSnapshot] = field(default_factory=dict)

    def to_json(self) -> str:
        robots = {
            n: {
                "x": r.pose.x,
                "y": r.pose.y,
                "theta": r.pose.theta,
                "battery": r.battery,
                "charging": r.charging,
            }
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
            robots[name] = RobotSnapshot(st.pose, float(st.battery), bool(st.charging))
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
        charging = r.get("charging", False)
        if not isinstance(charging, bool):
            raise ConfigError(str(path), f"{where}.charging", f"must be true or false, got {charging!r}")
        robots[str(name)] = RobotSnapshot(pose, battery, charging)
    return SimSnapshot(fleet, t, robots)


def _number(v: Any, path: Path, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(str(path), where, f"must be a finite number, got {v!r}")
    return float(v)


def simulator_from_config(config: FleetConfig, snapshot: SimSnapshot | None = None) -> Simulator:
    """A :class:`sim.simulator.Simulator` with every robot of a fleet config; with a
    ``snapshot``, its clock starts at the snapshot's time and its robots at their saved poses,
    batteries and docking states (a robot whose saved pose is not free starts at its configured
    start)."""
    from fleet.clock import SimClock
    from sim.simulator import Simulator

    sim = Simulator(config.grid, config.sim, SimClock(snapshot.t if snapshot is not None else 0.0))
    for spec in config.robots:
        if snapshot is None:
            sim.add_robot(spec)
            continue
        try:
            sim.add_robot(snapshot.respec(spec))
        except BackendError as e:
            logger.warning("%s starts at its configured pose: %s", spec.name, e)
            sim.add_robot(spec)
            continue
        saved = snapshot.robots.get(spec.name)
        if saved is not None and saved.charging:
            # docked: charging until the first step recomputes it (standing on a charger)
            sim.state.charging[sim.namespaces.index(spec.namespace)] = True
    return sim


def resume_simulator(config: FleetConfig, state_dir: Path) -> Simulator:
    """The simulator of ``config`` resumed from the snapshot in ``state_dir`` (fresh if there
    is none; the directory is created). Raises :class:`~fleet.errors.ConfigError` for a file
    there that is not a snapshot of this fleet."""
    state_dir.mkdir(parents=True, exist_ok=True)
    snap = read(state_dir / SNAPSHOT_FILE, config.name)
    if snap is not None:
        logger.warning(
            "resuming the simulator from %s: t=%.1f s, %d robots at their saved poses",
            state_dir / SNAPSHOT_FILE,
            snap.t,
            len(snap.robots),
        )
    return simulator_from_config(config, snap)


class SnapshotWriter:
    """Writes ``sim``'s snapshot to ``state_dir`` at most every ``every_s`` wall seconds
    (:meth:`maybe`, called as often as the caller likes) and on :meth:`save`. A failed write
    (a full disk) is logged and the run goes on."""

    def __init__(
        self, sim: Simulator, config: FleetConfig, state_dir: Path, every_s: float = SNAPSHOT_EVERY_S
    ) -> None:
        self.sim = sim
        self.fleet = config.name
        self.names = {r.namespace: r.name for r in config.robots}
        self.path = state_dir / SNAPSHOT_FILE
        self.every_s = float(every_s)
        self.next_wall = 0.0
        self.writes = 0

    def maybe(self, wall: float | None = None) -> None:
        """Write if ``every_s`` passed since the last write (``wall``: monotonic seconds now)."""
        w = time.monotonic() if wall is None else wall
        if w >= self.next_wall:
            self.next_wall = w + self.every_s
            self.save()

    def save(self) -> None:
        try:
            write(self.path, take(self.sim, self.fleet, self.names))
            self.writes += 1
        except OSError as e:  # a full disk must not stop the simulator
            logger.warning("cannot write the simulator snapshot %s: %s", self.path, e)
