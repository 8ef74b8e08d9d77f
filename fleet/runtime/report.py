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
  ``t_reassigned``); ``assignments``: one entry per patrol assignment (``task_id``, ``route``, ``robot``,
  ``t_assigned``, ``laps``, ``t_first_lap``, ``ended``, ``end_reason``). Over a long run
  these two lists hold the newest thousands only (:mod:`fleet.coordination.archive`); the
  counts and laps above cover the whole run;
* ``min_battery``: the lowest battery fraction any robot reported during the run;
  ``idle_fraction``: share of the local robots' agent ticks spent idle (no work, not charging);
  ``p95_wait_s`` (traffic management only): 95th percentile over robots of their total wait;
  ``teleports`` (SUMO only, else ``null``): vehicles SUMO moved on after waiting too long;
* ``throughput_laps_per_robot_hour``: ``laps_completed`` per robot per simulated hour;
  ``mean_wait_s`` (traffic management only): mean over robots of the time they waited for
  right of way; ``traffic`` (traffic management only, else ``null``): ``robots_managed``,
  ``deadlock_s``, ``deadlock_events`` (``t``, ``robots``), ``mean_wait_s``, ``p95_wait_s``, ``max_wait_s``,
  ``wait_events``, ``cycles_detected`` / ``cycles_resolved`` (wait-for cycles the manager
  found and broke), ``reroutes``, ``sidesteps``, ``nudges``, ``stalls`` (robots treated as
  stopped after no progress);
* ``per_robot``: one entry per robot: ``name``, ``namespace``, ``distance_m``, ``laps``,
  ``battery_final``, ``battery_min`` (the lowest it reported), ``final_state`` (the tree's mode at the end, or ``dead`` / ``unknown``),
  ``leaf``, ``task_id``, ``collisions``, ``charges`` (times it went to charge), ``goals``
  (that robot's goal metrics, as below; robots of other processes: empty);
* ``goals``: goal-level metrics of the fleet's navigation goals (:mod:`fleet.runtime.goal_log`):
  ``sent``, ``succeeded``, ``failed``, ``canceled``, ``failed_by_code`` (``{code name:
  goals}``), ``success_rate`` (succeeded / (succeeded + failed)), ``recoveries``,
  ``recoveries_per_goal``, ``max_recoveries``, ``time_over_straight`` and
  ``time_over_roadmap`` (time taken by succeeded goals over the time of the straight-line /
  roadmap optimum at top speed).
  Each ``per_robot`` entry also has ``safety_stops`` (times its safety watchdog stopped it:
  localization lost, navigation server down; :mod:`fleet.diagnostics`);
* ``safety_stops``: the robots' safety stops summed (robots of this process).

Trajectories (for :mod:`fleet.viz.plot`) are kept on the object but not written to JSON:
the world's own (the simulator and SUMO sample every robot every 0.5 s) for the robots of
this process, else bounded ones sampled from the robots' statuses on the bus
(:class:`fleet.runtime.trajectory.Trajectory`: at most 1024 samples per robot, decimated
evenly over the run).

:class:`ReportBuilder` assembles a :class:`RunReport` from what a run leaves behind (the
world, the coordinator's state, the traffic policy, the latest status of each robot).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.messages import StatusRecord
from fleet.types import TaskKind

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from fleet.coordination.coordinator import Assignment, CoordinatorState, Reassignment
    from fleet.runtime.goal_log import GoalMetrics
    from fleet.runtime.worlds import World
    from fleet.traffic.policy import ReservationTraffic

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
    goals: dict[str, Any] = field(default_factory=dict)
    safety_stops: int = 0
    battery_min: float = 1.0


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
    rejected_messages: int = 0
    interrupted: bool = False
    throughput_laps_per_robot_hour: float = 0.0
    mean_wait_s: float | None = None
    traffic: dict[str, Any] | None = None
    picks_assigned: int = 0
    picks_completed: int = 0
    goals: dict[str, Any] = field(default_factory=dict)
    safety_stops: int = 0
    #: Tasks of the task service by state and by kind (``None`` without a coordinator).
    tasks: dict[str, Any] | None = None
    #: Every pause, resume, e-stop and release: when (fleet and wall time), by whom, why.
    control_events: list[dict[str, Any]] = field(default_factory=list)
    min_battery: float = 1.0
    p95_wait_s: float | None = None
    idle_fraction: float = 0.0
    teleports: int | None = None
    trajectories: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready dict (trajectories left out)."""
        d = asdict(replace(self, trajectories={}))
        d.pop("trajectories", None)
        d["sim_time_s"] = round(self.sim_time_s, 3)
        d["wall_time_s"] = round(self.wall_time_s, 3)
        d["throughput_laps_per_robot_hour"] = round(self.throughput_laps_per_robot_hour, 3)
        if self.mean_wait_s is not None:
            d["mean_wait_s"] = round(self.mean_wait_s, 3)
        for r in d["per_robot"]:
            r["distance_m"] = round(r["distance_m"], 2)
            r["battery_final"] = round(r["battery_final"], 4)
            r["battery_min"] = round(r["battery_min"], 4)
        d["min_battery"] = round(self.min_battery, 4)
        d["idle_fraction"] = round(self.idle_fraction, 4)
        if self.p95_wait_s is not None:
            d["p95_wait_s"] = round(self.p95_wait_s, 3)
        return d

    def write_json(self, path: str | Path) -> Path:
        """Write :meth:`to_dict` as indented JSON to ``path`` (parent folders are created)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return p

    def summary(self) -> str:
        """The end-of-run summary as plain text (several lines, no trailing newline); see
        :mod:`fleet.viz.summary`."""
        from fleet.viz.summary import summary_text

        return summary_text(self.to_dict())


@dataclass
class ReportBuilder:
    """Builds the :class:`RunReport` of one run.

    Args:
        config: the fleet config; its robots give the report's row order.
        backend: the backend name; ``speed``: the requested multiple of real time.
        local: the robots whose agents ran in this process (their trajectories come from the
            world; the others' from ``bus_trajectory``).
        t0: the simulated time the loop started at (for the throughput).
        t_end: the simulated time the loop ended at (default: the world's clock now).
    """

    config: FleetConfig
    backend: str
    speed: float
    local: Sequence[str]
    t0: float = 0.0
    t_end: float | None = None
    #: Laps per robot of the report being built (asked of the coordinator once, not per row).
    _laps: dict[str, int] = field(default_factory=dict, init=False, repr=False)

    # long: one keyword per part of the report, passed straight through
    def build(
        self,
        world: World,
        records: Mapping[str, StatusRecord],
        *,
        wall_s: float,
        interrupted: bool,
        state: CoordinatorState | None = None,
        traffic: ReservationTraffic | None = None,
        charges: Mapping[str, int] | None = None,
        goals: Mapping[str, GoalMetrics] | None = None,
        min_battery: Mapping[str, float] | None = None,
        mode_ticks: Mapping[str, int] | None = None,
        bus_trajectory: Callable[[str], list[tuple[float, float, float]]] = lambda name: [],
        malformed: int = 0,
        rejected: int = 0,
        safety_stops: Mapping[str, int] | None = None,
        tasks: dict[str, Any] | None = None,
        control_events: Sequence[dict[str, Any]] = (),
    ) -> RunReport:
        """The report: ``records`` are the latest status per robot; ``state`` the coordinator's
        (``None`` without a coordinator: laps come from the records); ``traffic`` the traffic
        policy when traffic management was on; ``charges`` times each local robot went to
        charge; ``goals`` each local robot's goal metrics; ``min_battery`` the lowest battery each
        local robot reported (robots of other processes: their last one); ``mode_ticks`` agent
        ticks per tree mode over the local robots; ``malformed`` payloads this process dropped
        unparsed (status bus, clock, navigation states, task service queries); ``rejected``
        well-formed messages it ignored: orders and grants not from the live coordinator,
        clock and navigation states not from a live simulator (``docs/protocol.md``)."""
        names = [r.name for r in self.config.robots if r.name in records or r.name in self.local]
        self._laps = state.laps_by_robot() if state is not None else {}
        rows = [self._row(n, records.get(n), state, charges or {}, min_battery or {}) for n in names]
        fleet_goals = _merge_goals(rows, goals or {})
        for row in rows:
            row.safety_stops = (safety_stops or {}).get(row.name, 0)
        trajectories = {n: self._trajectory(world, n, bus_trajectory) for n in names}
        collisions = world.collisions()
        if collisions is None:  # a blind world: every robot reports its own contacts
            collisions = sum(r.collisions for r in rows) // 2
        now = world.clock.now() if self.t_end is None else self.t_end
        laps = state.laps_completed() if state is not None else sum(r.laps for r in rows)
        robot_hours = len(rows) * max(0.0, now - self.t0) / 3600.0
        tblock = traffic_dict(traffic, now) if traffic is not None else None
        deadlocks = (
            traffic.deadlocks if traffic is not None else (state.deadlocks if state is not None else 0)
        )
        return RunReport(
            config=str(self.config.path),
            backend=self.backend,
            robots=len(rows),
            # the run's own time (not the robots' clock), to the microsecond: a run that ended
            # at t0 + duration must not report 89.999999999 s for 90
            sim_time_s=round(float(now - self.t0), 6),
            wall_time_s=float(wall_s),
            speed=self.speed,
            patrols_assigned=state.assigned(TaskKind.PATROL) if state is not None else 0,
            patrols_completed=state.patrols_completed() if state is not None else 0,
            laps_completed=laps,
            collisions=int(collisions),
            deadlocks=int(deadlocks),
            reassignments=state.reassignment_count() if state is not None else 0,
            per_robot=rows,
            laps_by_route=state.laps_by_route() if state is not None else {},
            reassignment_events=[reassignment_dict(r) for r in state.reassignments]
            if state is not None
            else [],
            assignments=[assignment_dict(a) for a in state.assignments] if state is not None else [],
            malformed_messages=int(malformed),
            rejected_messages=int(rejected),
            interrupted=interrupted,
            trajectories=trajectories,
            throughput_laps_per_robot_hour=laps / robot_hours if robot_hours > 0 else 0.0,
            mean_wait_s=traffic.mean_wait_s(now) if traffic is not None else None,
            traffic=tblock,
            picks_assigned=state.assigned(TaskKind.PICK) if state is not None else 0,
            picks_completed=state.picks_completed() if state is not None else 0,
            goals=fleet_goals.to_dict() if goals else {},
            safety_stops=sum(r.safety_stops for r in rows),
            tasks=tasks,
            control_events=list(control_events),
            min_battery=min((r.battery_min for r in rows), default=1.0),
            p95_wait_s=float(tblock["p95_wait_s"]) if tblock is not None else None,
            idle_fraction=_idle_fraction(mode_ticks or {}),
            teleports=_teleports(world),
        )

    def _row(
        self,
        name: str,
        rec: StatusRecord | None,
        state: CoordinatorState | None,
        charges: Mapping[str, int],
        min_battery: Mapping[str, float],
    ) -> RobotReport:
        spec = self.config.robot(name)
        dead = state is not None and name in state.robots and not state.robots[name].alive
        if state is not None:
            laps = self._laps.get(name, 0)
        else:
            laps = int(rec.laps) if rec is not None else 0
        return RobotReport(
            name=name,
            namespace=spec.namespace,
            distance_m=float(rec.distance_m) if rec is not None else 0.0,
            laps=laps,
            battery_final=float(rec.battery) if rec is not None else float(spec.battery),
            battery_min=min_battery.get(name, float(rec.battery) if rec is not None else float(spec.battery)),
            final_state="dead" if dead else (str(rec.mode) if rec is not None else "unknown"),
            leaf=str(rec.leaf) if rec is not None else "",
            task_id=rec.task_id if rec is not None else None,
            collisions=int(rec.collisions) if rec is not None else 0,
            charges=charges.get(name, 0),
        )

    def _trajectory(
        self, world: World, name: str, bus_trajectory: Callable[[str], list[tuple[float, float, float]]]
    ) -> list[tuple[float, float, float]]:
        traj = world.trajectory(self.config.robot(name).namespace) if name in self.local else None
        return traj if traj is not None else bus_trajectory(name)


def traffic_dict(tp: ReservationTraffic, now: float) -> dict[str, Any]:
    """The report's ``traffic`` block (see the module docstring)."""
    m = tp.manager
    met = m.metrics
    waits = [m.wait_stats(r, now)[0] for r in m.robots]
    return {
        "robots_managed": len(m.robots),
        "deadlock_s": tp.deadlock_s,
        "deadlock_events": [{"t": round(t, 3), "robots": list(rs)} for t, rs in tp.deadlock_events],
        "mean_wait_s": round(tp.mean_wait_s(now), 3),
        "p95_wait_s": round(p95(waits), 3),
        "max_wait_s": round(max(waits, default=0.0), 3),
        "wait_events": met.wait_events,
        "cycles_detected": met.deadlocks_detected,
        "cycles_resolved": met.deadlocks_resolved,
        "reroutes": met.reroutes,
        "sidesteps": met.sidesteps,
        "nudges": met.nudges,
        "stalls": met.deaths,
    }


def _teleports(world: World) -> int | None:
    """SUMO's teleports (vehicles it moved on after waiting too long: its deadlocks); ``None``
    for worlds that do not teleport."""
    n = getattr(world, "teleports", None)
    return int(n) if isinstance(n, int) else None


def _idle_fraction(mode_ticks: Mapping[str, int]) -> float:
    """Share of agent ticks spent in mode ``idle`` (0 when nothing ticked)."""
    total = sum(mode_ticks.values())
    return mode_ticks.get("idle", 0) / total if total else 0.0


def p95(values: Sequence[float]) -> float:
    """The 95th percentile of ``values`` (nearest rank; 0 for none)."""
    if not values:
        return 0.0
    s = sorted(values)
    return float(s[min(len(s) - 1, max(0, math.ceil(0.95 * len(s)) - 1))])


def reassignment_dict(r: Reassignment) -> dict[str, Any]:
    """One entry of the report's ``reassignment_events``."""
    return {
        "t": round(r.t, 3),
        "route": r.route,
        "from_robot": r.from_robot,
        "reason": r.reason,
        "old_task_id": r.old_task_id,
        "to_robot": r.to_robot,
        "new_task_id": r.new_task_id,
        "t_reassigned": None if r.t_reassigned is None else round(r.t_reassigned, 3),
    }


def assignment_dict(a: Assignment) -> dict[str, Any]:
    """One entry of the report's ``assignments``."""
    return {
        "task_id": a.task_id,
        "route": a.route,
        "robot": a.robot,
        "t_assigned": round(a.t_assigned, 3),
        "laps": a.laps,
        "t_first_lap": None if a.t_first_lap is None else round(a.t_first_lap, 3),
        "ended": None if a.ended is None else round(a.ended, 3),
        "end_reason": a.end_reason,
    }


def _merge_goals(rows: Sequence[RobotReport], goals: Mapping[str, GoalMetrics]) -> GoalMetrics:
    """Put each robot's goal metrics on its row; returns the fleet's (their sum)."""
    from fleet.runtime.goal_log import GoalMetrics

    fleet = GoalMetrics()
    for row in rows:
        m = goals.get(row.name)
        if m is not None:
            row.goals = m.to_dict()
            fleet.add(m)
    return fleet


def sum_counts(counts: Iterable[Mapping[str, int]]) -> dict[str, int]:
    """Key-wise sum of count mappings (the agents' ticks per mode)."""
    out: dict[str, int] = {}
    for c in counts:
        for k, v in c.items():
            out[k] = out.get(k, 0) + v
    return out
