"""The result of one fleet run: a :class:`RunReport` that serializes to JSON and prints a summary.

JSON fields (``RunReport.to_dict``), units in the names:

* ``config``, ``backend``: the config file and the navigation backend name;
* ``robots``: number of robots; ``sim_time_s``: simulated seconds run; ``wall_time_s``: wall
  seconds the run took; ``speed``: requested multiple of real time (0 = as fast as possible);
* ``patrols_assigned``: patrol assignments made (each with its own id);
  ``patrols_completed``: assignments whose robot finished at least one lap;
  ``laps_completed``: laps over all assignments; ``laps_by_route``: ``{route: laps}``;
* ``picks_assigned``: pick assignments made (picking trees only; each with its own id, a
  reassigned pick counts again); ``picks_completed``: picks done (each pick at most once);
* ``collisions``: robot-robot contact events; ``deadlocks``: with traffic management, sets
  of robots that waited on each other (a wait-for cycle) for more than ``traffic.deadlock_s``
  (each set counted once while it lasts); without it (no wait-for relation exists), times a
  robot was reported stuck with another robot within 1.5 m; ``reassignments``: routes (or
  picks) taken back from a robot (dead, stuck, charging); ``reassignment_events``: one entry per reassignment (``t``, ``route``,
  ``from_robot``, ``reason``, ``old_task_id``, ``to_robot``, ``new_task_id``,
  ``t_reassigned``); ``assignments``: every assignment (``task_id``, ``route``, ``robot``,
  ``t_assigned``, ``laps``, ``t_first_lap``, ``ended``, ``end_reason``);
* ``throughput_laps_per_robot_hour``: ``laps_completed`` per robot per simulated hour;
  ``mean_wait_s`` (traffic management only): mean over robots of the time they waited for
  right of way; ``traffic`` (traffic management only, else ``null``): ``robots_managed``,
  ``deadlock_s``, ``deadlock_events`` (``t``, ``robots``), ``mean_wait_s``, ``max_wait_s``,
  ``wait_events``, ``cycles_detected`` / ``cycles_resolved`` (wait-for cycles the manager
  found and broke), ``reroutes``, ``sidesteps``, ``nudges``, ``stalls`` (robots treated as
  stopped after no progress);
* ``per_robot``: one entry per robot: ``name``, ``namespace``, ``distance_m``, ``laps``,
  ``battery_final``, ``final_state`` (the tree's mode at the end, or ``dead`` / ``unknown``),
  ``leaf``, ``task_id``, ``collisions``, ``charges`` (times it went to charge).

Trajectories (for :mod:`fleet.viz.plot`) are kept on the object but not written to JSON.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

REQUIRED_FIELDS = (
    "robots",
    "sim_time_s",
    "wall_time_s",
    "patrols_assigned",
    "patrols_completed",
    "laps_completed",
    "collisions",
    "deadlocks",
    "reassignments",
    "per_robot",
)
ROBOT_FIELDS = ("name", "distance_m", "laps", "battery_final", "final_state")


@dataclass
class RobotReport:
    """One robot's result. Distances in meters, battery a fraction in [0, 1]."""

    name: str
    namespace: str
    distance_m: float
    laps: int
    battery_final: float
    final_state: str
    leaf: str = ""
    task_id: str | None = None
    collisions: int = 0
    charges: int = 0


@dataclass
class RunReport:
    """Everything a run measured (see the module docstring for the JSON fields)."""

    config: str
    backend: str
    robots: int
    sim_time_s: float
    wall_time_s: float
    speed: float
    patrols_assigned: int
    patrols_completed: int
    laps_completed: int
    collisions: int
    deadlocks: int
    reassignments: int
    per_robot: list[RobotReport]
    laps_by_route: dict[str, int] = field(default_factory=dict)
    reassignment_events: list[dict[str, Any]] = field(default_factory=list)
    assignments: list[dict[str, Any]] = field(default_factory=list)
    malformed_messages: int = 0
    interrupted: bool = False
    throughput_laps_per_robot_hour: float = 0.0
    mean_wait_s: float | None = None
    traffic: dict[str, Any] | None = None
    picks_assigned: int = 0
    picks_completed: int = 0
    trajectories: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready dict (trajectories left out)."""
        d = asdict(self)
        d.pop("trajectories", None)
        d["sim_time_s"] = round(self.sim_time_s, 3)
        d["wall_time_s"] = round(self.wall_time_s, 3)
        d["throughput_laps_per_robot_hour"] = round(self.throughput_laps_per_robot_hour, 3)
        if self.mean_wait_s is not None:
            d["mean_wait_s"] = round(self.mean_wait_s, 3)
        for r in d["per_robot"]:
            r["distance_m"] = round(r["distance_m"], 2)
            r["battery_final"] = round(r["battery_final"], 4)
        return d

    def write_json(self, path: str | Path) -> Path:
        """Write :meth:`to_dict` as indented JSON to ``path`` (parent folders are created)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return p

    def summary(self) -> str:
        """A short human-readable summary (several lines, no trailing newline)."""
        rate = self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else float("inf")
        lines = [
            f"{'interrupted' if self.interrupted else 'finished'}: {self.robots} robots, "
            f"{self.sim_time_s:.1f} s simulated in {self.wall_time_s:.1f} s wall ({rate:.1f}x real time)",
            f"patrols: {self.patrols_assigned} assigned, {self.patrols_completed} completed, "
            f"{self.laps_completed} laps"
            + (
                " (" + ", ".join(f"{k}: {v}" for k, v in self.laps_by_route.items()) + ")"
                if self.laps_by_route
                else ""
            ),
        ]
        if self.picks_assigned:
            lines.append(f"picks: {self.picks_assigned} assigned, {self.picks_completed} completed")
        lines += [
            f"collisions: {self.collisions}   deadlocks: {self.deadlocks}   reassignments: {self.reassignments}"
            f"   throughput: {self.throughput_laps_per_robot_hour:.1f} laps/robot-hour",
        ]
        if self.traffic is not None:
            t = self.traffic
            lines.append(
                f"traffic: mean wait {t['mean_wait_s']:.1f} s (max {t['max_wait_s']:.1f} s), "
                f"wait-for cycles {t['cycles_detected']} found / {t['cycles_resolved']} resolved, "
                f"{t['reroutes']} reroutes, {t['sidesteps']} side steps, {t['stalls']} stalls"
            )
        for e in self.reassignment_events:
            to = f"-> {e['to_robot']} at {e['t_reassigned']:.1f} s" if e.get("to_robot") else "(waiting)"
            lines.append(f"  t={e['t']:.1f} s {e['route']}: {e['from_robot']} {e['reason']} {to}")
        width = max((len(r.name) for r in self.per_robot), default=5)
        lines.append(f"  {'robot':<{width}}  {'dist m':>8}  {'laps':>4}  {'battery':>7}  state")
        for r in self.per_robot:
            lines.append(
                f"  {r.name:<{width}}  {r.distance_m:8.1f}  {r.laps:4d}  {r.battery_final:7.0%}  {r.final_state}"
            )
        return "\n".join(lines)
