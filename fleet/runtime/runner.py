"""The fleet loop: simulator (or a remote backend), one agent per robot, the coordinator, pacing.

:class:`FleetRunner` owns the loop of ``docs/architecture.md``. Per iteration it advances the
world by one step (the in-process simulator steps by ``sim.step_s``; a remote world waits for
the remote simulator's clock to move); every ``1 / tick_hz`` simulated seconds it ticks each
local agent once (which publishes its status), then runs one coordinator cycle. ``speed``
paces simulated time at that multiple of wall time (``0`` = as fast as possible); a live
table (TTY) or a progress line every few wall seconds (not a TTY) shows the fleet.

Zenoh: the runner opens exactly one session, shared by its agents and its coordinator, and
always closes it (also on Ctrl-C or an error). With an in-process world it is a router
*listening* on the endpoint (other processes, e.g. ``fleet status``, connect to it); with a
remote world it *connects* to the endpoint where ``fleet sim`` listens.

Agents and the coordinator in the same process exchange their messages directly as well as
over the bus (the coordinator ignores the bus copies of its local robots' statuses), so an
in-process run with ``speed=0`` does not depend on network timing and is reproducible.

Backends are pluggable by name in :data:`BACKENDS` (``name -> factory``); a factory builds a
:class:`World` lazily, so importing the core never imports rclpy or libsumo. Registered
here: ``sim`` (the kinematic simulator, in-process) and ``remote`` (a simulator served by
``fleet sim`` in another process, reached over Zenoh)."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

from fleet.clock import WallClock
from fleet.config.model import FleetConfig
from fleet.errors import BackendError, ConfigError
from fleet.runtime.backends import BACKENDS, backend_names, world_factory
from fleet.runtime.report import RobotReport, RunReport
from fleet.runtime.worlds import World

#: Progress lines (when stdout is not a TTY) are printed this often (wall seconds).
PROGRESS_EVERY_S = 5.0


#: The live table is redrawn this often (wall seconds).
TABLE_EVERY_S = 0.25


#: Trajectory sampling period for worlds that do not record trajectories (sim seconds).
TRAJECTORY_PERIOD_S = 0.5


@dataclass
class _Seen:
    """The last status of a robot seen on the bus (for remote robots' report rows)."""

    rec: Any
    trajectory: list[tuple[float, float, float]]


class FleetRunner:
    """Run a fleet: world + agents + coordinator on one Zenoh session. See the module docstring.

    Args:
        config: the fleet config (``load_config(path, robots=N)`` already applied the count).
        duration: simulated seconds to run (``None``: until interrupted).
        speed: multiple of real time; ``0`` runs as fast as possible.
        endpoint: the Zenoh endpoint (default: the config's ``bus.endpoint``).
        backend: a name in :data:`BACKENDS`.
        agents: ``"all"`` (every robot of the config), or the robot names to run here.
        coordinator: whether this process runs the coordinator.
        live: show the live table (default: when ``out`` is a TTY).
        tree_kind: the behavior tree of every local agent (``patrol`` or ``picking``).
        out: where the live table, progress and messages go (default ``sys.stdout``).
        listen: listen on the endpoint (router) instead of connecting; default: listen for
            in-process worlds, connect for remote ones.
        traffic: reservation-based traffic management (``docs/traffic.md``); default: the
            config's ``traffic.enabled``.
    """

    def __init__(
        self,
        config: FleetConfig,
        *,
        duration: float | None = 60.0,
        speed: float = 1.0,
        endpoint: str | None = None,
        backend: str = "sim",
        agents: str | Sequence[str] = "all",
        coordinator: bool = True,
        live: bool | None = None,
        tree_kind: str = "patrol",
        out: TextIO | None = None,
        listen: bool | None = None,
        traffic: bool | None = None,
    ) -> None:
        if backend not in BACKENDS:
            raise ConfigError(
                str(config.path),
                "backend",
                f"unknown backend {backend!r}; known: {', '.join(backend_names())}",
            )
        if speed < 0 or not math.isfinite(speed):
            raise ConfigError(
                str(config.path), "speed", f"must be >= 0 (0 = as fast as possible), got {speed}"
            )
        if duration is not None and (duration <= 0 or not math.isfinite(duration)):
            raise ConfigError(
                str(config.path), "duration", f"must be a positive number of seconds, got {duration}"
            )
        names = [r.name for r in config.robots]
        if agents == "all":
            self.agent_names = names
        else:
            self.agent_names = list(agents)
            for a in self.agent_names:
                if a not in names:
                    raise ConfigError(
                        str(config.path), "robots", f"no robot named {a!r} (robots: {', '.join(names)})"
                    )
        self.config = config
        self.duration = duration
        self.speed = float(speed)
        self.endpoint = endpoint or config.endpoint
        self.backend_name = backend
        self.run_coordinator = coordinator
        self.out = out or sys.stdout
        self.live = self.out.isatty() if live is None else live
        self.tree_kind = tree_kind
        self.listen = listen
        self.traffic = config.traffic.enabled if traffic is None else bool(traffic)
        if self.traffic and tree_kind != "patrol":
            raise ConfigError(
                str(config.path), "traffic", f"traffic management drives patrol trees only, not {tree_kind!r}"
            )
        #: The traffic policy (:class:`fleet.traffic.ReservationTraffic`) when traffic is on.
        self.traffic_policy: Any = None
        self.stop_event = threading.Event()
        self._t0 = 0.0
        self.world: World | None = None
        self.agents: list[Any] = []
        self.coordinator: Any = None
        self.bus: Any = None
        self._seen: dict[str, _Seen] = {}
        self._seen_lock = threading.Lock()
        #: Called as ``observer(sim_time, runner)`` once per agent tick, after the agents and
        #: the coordinator cycle (e.g. to sample fleet metrics; see :mod:`fleet.loadtest`).
        self.observers: list[Callable[[float, FleetRunner], None]] = []

    # -- the run -------------------------------------------------------------------------

    def run(self) -> RunReport:
        """Run until ``duration`` simulated seconds passed or :meth:`stop` / Ctrl-C; always
        close the agents, the bus and the session. Returns the report (``interrupted`` set
        if it was stopped early)."""
        from fleet.bus.session import open_session
        from fleet.bus.status_bus import StatusBus

        factory = world_factory(self.backend_name)
        remote = getattr(factory, "bus_elsewhere", False)
        listen = (not remote) if self.listen is None else self.listen
        wall = WallClock()
        t_wall0 = wall.now()
        session = open_session(self.endpoint, "router" if listen else "client")
        interrupted = False
        try:
            self.bus = StatusBus(session)
            self.bus.subscribe_statuses(self._on_bus_status)
            specs = [self.config.robot(n) for n in self.agent_names]
            self.world = factory(self.config, specs, session)
            world = self.world
            if self.run_coordinator:
                from fleet.coordination.coordinator import Coordinator

                if self.traffic:
                    from fleet.traffic.policy import traffic_from_config

                    self.traffic_policy = traffic_from_config(self.config)
                self.coordinator = Coordinator(
                    self.config,
                    self.bus,
                    world.clock,
                    traffic=self.traffic_policy,
                    local_robots=set(self.agent_names),
                    task_kind=self.tree_kind,
                )
            feed = self.coordinator.feed_local if self.coordinator is not None else None
            from fleet.runtime.agent import RobotAgent

            for spec in specs:
                agent = RobotAgent(
                    spec.namespace,
                    world.backend(spec.namespace),
                    world.clock,
                    self.bus,
                    tree_kind=self.tree_kind,
                    battery_model=self.config.sim.battery,
                    tick_hz=self.config.tick_hz,
                    on_status=feed,
                    traffic=self.traffic,
                )
                self.agents.append(agent)
            if self.coordinator is not None:
                self.coordinator.local_deliver = {a.name: a.deliver for a in self.agents}
                self.coordinator.local_grant_deliver = {a.name: a.deliver_grant for a in self.agents}
            try:
                self._loop(world, wall, t_wall0)
            except KeyboardInterrupt:
                interrupted = True
            except BackendError as e:  # e.g. the remote simulator went away: end, still report
                print(f"warning: {e}; ending the run", file=self.out, flush=True)
                interrupted = True
            interrupted = interrupted or self.stop_event.is_set()
            return self._report(world, wall.now() - t_wall0, interrupted)
        finally:
            self._close(session)

    def stop(self) -> None:
        """Ask the loop to end after the current iteration (thread-safe)."""
        self.stop_event.set()

    def _loop(self, world: World, wall: WallClock, t_wall0: float) -> None:
        clock = world.clock
        period = 1.0 / self.config.tick_hz
        t0 = clock.now()
        self._t0 = t0
        next_tick = t0
        end = None if self.duration is None else t0 + self.duration
        table = self._make_table()
        next_draw = wall.now()
        next_progress = wall.now() + PROGRESS_EVERY_S
        eps = 1e-9
        try:
            while not self.stop_event.is_set():
                now = clock.now()
                if end is not None and now >= end - eps:
                    break
                if now >= next_tick - eps:
                    for a in self.agents:
                        a.tick()
                    if self.coordinator is not None:
                        self.coordinator.cycle()
                    for observe in self.observers:
                        observe(now, self)
                    next_tick += period
                    if next_tick <= now:  # a remote clock jumped ahead: do not tick in a burst
                        next_tick = now + period
                world.advance()
                if not world.remote and self.speed > 0:
                    lag = (clock.now() - t0) / self.speed - (wall.now() - t_wall0)
                    if lag > 0:
                        time.sleep(lag)
                w = wall.now()
                if table is not None and w >= next_draw:
                    table.update(self.records(), self._alive(), clock.now())
                    next_draw = w + TABLE_EVERY_S
                elif table is None and w >= next_progress:
                    self._progress(clock.now(), w - t_wall0)
                    next_progress = w + PROGRESS_EVERY_S
        finally:
            if table is not None:
                table.update(self.records(), self._alive(), clock.now(), force=True)
                close = getattr(table, "close", None)
                if close is not None:
                    close()

    # -- status, table, report ---------------------------------------------------------

    def _on_bus_status(self, rec: Any) -> None:
        with self._seen_lock:
            s = self._seen.get(rec.robot)
            if s is None:
                s = self._seen[rec.robot] = _Seen(rec, [])
            s.rec = rec
            if rec.pose is not None and (
                not s.trajectory or rec.t >= s.trajectory[-1][0] + TRAJECTORY_PERIOD_S
            ):
                s.trajectory.append((float(rec.t), float(rec.pose[0]), float(rec.pose[1])))

    def records(self) -> list[Any]:
        """The latest status record of every robot known here (local agents first)."""
        out: dict[str, Any] = {}
        for a in self.agents:
            if a.last_status is not None:
                out[a.name] = a.last_status
        with self._seen_lock:
            for name, s in self._seen.items():
                out.setdefault(name, s.rec)
        return [out[k] for k in sorted(out, key=_robot_sort_key)]

    def _alive(self) -> set[str] | None:
        """Robots holding a liveliness token (None if nobody in this process watches them)."""
        return self.bus.alive() if self.coordinator is not None and self.bus is not None else None

    def _make_table(self) -> Any:
        if not self.live:
            return None
        try:
            from fleet.viz.table import LiveTable
        except ImportError:  # the table module is optional for the loop
            return None
        return LiveTable(self.out)

    def _progress(self, sim_t: float, wall_t: float) -> None:
        recs = self.records()
        laps = (
            self.coordinator.state.laps_completed()
            if self.coordinator is not None
            else sum(r.laps for r in recs)
        )
        charging = sum(1 for r in recs if r.mode == "charging")
        print(
            f"[t={sim_t:7.1f} s sim, {wall_t:6.1f} s wall] {len(recs)} robots, {laps} laps, {charging} charging",
            file=self.out,
            flush=True,
        )

    def _report(self, world: World, wall_s: float, interrupted: bool) -> RunReport:
        st = self.coordinator.state if self.coordinator is not None else None
        laps_by_robot = st.laps_by_robot() if st is not None else {}
        charges = {a.name: a.charges for a in self.agents}
        rows: list[RobotReport] = []
        trajectories: dict[str, list[tuple[float, float, float]]] = {}
        recs = {r.robot: r for r in self.records()}
        names = [r.name for r in self.config.robots if r.name in recs or r.name in self.agent_names]
        for name in names:
            spec = self.config.robot(name)
            rec = recs.get(name)
            dead = st is not None and name in st.robots and not st.robots[name].alive
            traj = world.trajectory(spec.namespace) if name in self.agent_names else None
            if traj is None:
                with self._seen_lock:
                    seen = self._seen.get(name)
                    traj = list(seen.trajectory) if seen is not None else []
            trajectories[name] = traj
            rows.append(
                RobotReport(
                    name=name,
                    namespace=spec.namespace,
                    distance_m=float(rec.distance_m) if rec is not None else 0.0,
                    laps=laps_by_robot.get(name, int(rec.laps) if rec is not None and st is None else 0),
                    battery_final=float(rec.battery) if rec is not None else float(spec.battery),
                    final_state="dead" if dead else (str(rec.mode) if rec is not None else "unknown"),
                    leaf=str(rec.leaf) if rec is not None else "",
                    task_id=rec.task_id if rec is not None else None,
                    collisions=int(rec.collisions) if rec is not None else 0,
                    charges=charges.get(name, 0),
                )
            )
        collisions = world.collisions()
        if collisions is None:
            collisions = sum(r.collisions for r in rows) // 2
        clock_t = world.clock.now()
        laps = st.laps_completed() if st is not None else sum(r.laps for r in rows)
        robot_hours = len(rows) * max(0.0, clock_t - self._t0) / 3600.0
        tp = self.traffic_policy
        deadlocks = tp.deadlocks if tp is not None else (st.deadlocks if st is not None else 0)
        return RunReport(
            config=str(self.config.path),
            backend=self.backend_name,
            robots=len(rows),
            sim_time_s=float(clock_t),
            wall_time_s=float(wall_s),
            speed=self.speed,
            patrols_assigned=len(st.assignments) if st is not None else 0,
            patrols_completed=st.patrols_completed() if st is not None else 0,
            laps_completed=laps,
            collisions=int(collisions),
            deadlocks=int(deadlocks),
            reassignments=len(st.reassignments) if st is not None else 0,
            per_robot=rows,
            laps_by_route=st.laps_by_route() if st is not None else {},
            reassignment_events=[_reassignment_dict(r) for r in st.reassignments] if st is not None else [],
            assignments=[_assignment_dict(a) for a in st.assignments] if st is not None else [],
            malformed_messages=int(getattr(self.bus, "malformed", 0) or 0),
            interrupted=interrupted,
            trajectories=trajectories,
            throughput_laps_per_robot_hour=laps / robot_hours if robot_hours > 0 else 0.0,
            mean_wait_s=tp.mean_wait_s(clock_t) if tp is not None else None,
            traffic=_traffic_dict(tp, clock_t) if tp is not None else None,
            picks_assigned=len(st.pick_assignments) if st is not None else 0,
            picks_completed=st.picks_completed() if st is not None else 0,
        )

    def collision_points(self) -> list[tuple[float, float]]:
        return self.world.collision_points() if self.world is not None else []

    def _close(self, session: Any) -> None:
        for a in self.agents:
            try:
                a.close()
            except Exception as e:  # noqa: BLE001 - keep closing the rest
                print(f"warning: closing agent {a.name}: {e}", file=sys.stderr)
        if self.world is not None:
            try:
                self.world.close()
            except Exception as e:  # noqa: BLE001
                print(f"warning: closing backend: {e}", file=sys.stderr)
        if self.bus is not None:
            try:
                self.bus.close()
            except Exception as e:  # noqa: BLE001
                print(f"warning: closing bus: {e}", file=sys.stderr)
        try:
            session.close()
        except Exception:  # noqa: BLE001 - already closed by the bus
            pass


def _traffic_dict(tp: Any, now: float) -> dict[str, Any]:
    """The report's ``traffic`` block (see :mod:`fleet.runtime.report`)."""
    m = tp.manager
    met = m.metrics
    waits = [m.wait_stats(r, now)[0] for r in m.robots]
    return {
        "robots_managed": len(m.robots),
        "deadlock_s": tp.deadlock_s,
        "deadlock_events": [{"t": round(t, 3), "robots": list(rs)} for t, rs in tp.deadlock_events],
        "mean_wait_s": round(tp.mean_wait_s(now), 3),
        "max_wait_s": round(max(waits, default=0.0), 3),
        "wait_events": met.wait_events,
        "cycles_detected": met.deadlocks_detected,
        "cycles_resolved": met.deadlocks_resolved,
        "reroutes": met.reroutes,
        "sidesteps": met.sidesteps,
        "nudges": met.nudges,
        "stalls": met.deaths,
    }


def _reassignment_dict(r: Any) -> dict[str, Any]:
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


def _assignment_dict(a: Any) -> dict[str, Any]:
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


def _robot_sort_key(name: str) -> tuple[str, int]:
    head = name.rstrip("0123456789")
    tail = name[len(head) :]
    return (head, int(tail) if tail else -1)


__all__ = ["FleetRunner"]
