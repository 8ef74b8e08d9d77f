"""The fleet loop: simulator (or a remote backend), one agent per robot, the coordinator, pacing.

:class:`FleetRunner` owns the loop of ``docs/architecture.md``. Per iteration it advances the
world by one step (the in-process simulator steps by ``sim.step_s``; a remote world waits for
the remote simulator's clock to move); every ``1 / tick_hz`` simulated seconds it ticks each
local agent once (which publishes its status, at most at ``bus.status_hz``), then runs one
coordinator cycle and calls the observers. ``speed`` paces simulated time at that multiple of
wall time with the one :class:`fleet.clock.Pacer` (``0`` = as fast as possible; a remote
world is paced by its simulator). A :class:`fleet.viz.display.FleetDisplay` shows the fleet:
by default the live table on a terminal, else progress lines every few wall seconds.

Zenoh: the runner opens exactly one session, shared by its agents and its coordinator, and
always closes it (also on Ctrl-C or an error). With an in-process world it is a router
*listening* on the endpoint (other processes, e.g. ``fleet status``, connect to it); with a
remote world it *connects* to the endpoint where ``fleet sim`` listens.

Agents and the coordinator in the same process exchange their messages directly (the
coordinator ignores the bus copies of its local robots' statuses, and local agents take no
orders from the bus), so an in-process run with ``speed=0`` does not depend on network timing
and is reproducible.

Leases (``docs/protocol.md``): the runner refuses (:class:`~fleet.errors.LeaseError`) to drive
a robot that already has a live agent; with the coordinator it takes the coordinator lease
(refused if another coordinator is live) with a new epoch, kept in the durable task book.
Agents without a local coordinator follow the live lease, taking orders through their gate.

Backends: by name in :data:`fleet.runtime.backends.BACKENDS`; a factory builds a
:class:`~fleet.runtime.worlds.World` lazily (importing the core never imports rclpy or libsumo).
Diagnostics go to :mod:`logging` (logger ``fleet.runtime.runner``)."""

from __future__ import annotations

import logging
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from fleet.clock import Pacer, TickSchedule, WallClock
from fleet.config.model import FleetConfig
from fleet.errors import BackendError, ConfigError
from fleet.messages import StatusRecord
from fleet.runtime.arguments import check_args
from fleet.runtime.backends import world_factory
from fleet.runtime.closing import close_logged
from fleet.runtime.latch import Latch, LatchedBackend, WorldLatch
from fleet.runtime.report import ReportBuilder, RunReport, sum_counts
from fleet.runtime.scheduler import TickScheduler
from fleet.runtime.setup_progress import SetupProgress
from fleet.runtime.trajectory import BusView
from fleet.runtime.worlds import World, WorldFactory
from fleet.types import Mode, TreeKind
from fleet.viz.display import FleetDisplay, FleetSnapshot, default_display
from fleet.viz.table import robot_sort_key

if TYPE_CHECKING:
    import zenoh

    from fleet.bus.lease import CoordinatorLease, LeaseWatch
    from fleet.bus.link import LinkWatch
    from fleet.bus.session import Secure
    from fleet.bus.status_bus import StatusBus
    from fleet.coordination.coordinator import Coordinator
    from fleet.coordination.views import Observation
    from fleet.runtime.agent import RobotAgent
    from fleet.runtime.goal_log import GoalLog
    from fleet.runtime.service_host import ServiceHost
    from fleet.traffic.policy import ReservationTraffic

logger = logging.getLogger(__name__)


class FleetRunner:
    """Run a fleet: world + agents + coordinator on one Zenoh session. See the module docstring.

    Args:
        config: the fleet config (``load_config(path, robots=N)`` already applied the count).
        duration: simulated seconds to run (``None``: until interrupted).
        speed: multiple of real time; ``0`` runs as fast as possible.
        endpoint: the Zenoh endpoint (default: the config's ``bus.endpoint``).
        backend: a name in :data:`~fleet.runtime.backends.BACKENDS`.
        agents: ``"all"`` (every robot of the config), or the robot names to run here.
        coordinator: whether this process runs the coordinator.
        live: show the live table (default: when ``out`` is a TTY); ignored with ``display``.
        tree_kind: the config's initial tasks (see below).
        tree_file: a BehaviorTree.CPP XML tree every local agent runs instead (checked now: a
            bad file raises :class:`~fleet.errors.TreeError`); the orders it works on
            (``tree_kind``) are the file's.
        out: where the default display draws (default ``sys.stdout``).
        listen: listen on the endpoint (router) instead of connecting; default: listen for
            in-process worlds, connect for remote ones.
        traffic: reservation-based traffic management (``docs/traffic.md``); default: the
            config's ``traffic.enabled`` (on unless the config turns it off; an XML tree then
            runs without it).
        display: what shows the running fleet (default: :func:`fleet.viz.display.default_display`
            on ``out``; :class:`fleet.viz.display.NullDisplay` shows nothing).
        state_dir: the coordinator's durable task book (``docs/service.md``); a directory that
            holds one is resumed. ``None``: an in-memory book (the CLI defaults to a new directory
            under ``out/state/``). An in-process simulator keeps its snapshot there too and
            resumes from it (poses, batteries, docking states, the clock:
            :mod:`fleet.runtime.snapshot`): a killed ``fleet run`` resumes robots and tasks.
        api: ``HOST:PORT`` to serve the task service's HTTP API on (with the coordinator).
        secure: open the session on a secured bus (``docs/security.md``): as the router (with
            its credentials and access control) when this process listens, else as
            ``secure.identity``; the API then takes the key directory's token for mutating calls.
        ticking: ``"event"`` (default): each period a tree is ticked only when something it
            reads changed (:mod:`fleet.runtime.scheduler`; same decisions, far fewer ticks);
            ``"clock"``: every tree every period.

    ``tree_kind`` chooses the config's initial tasks (``patrol``: its routes, ``picking``:
    its picks, ``tasks``: both); every robot runs the tree that takes any task kind.
    Raises :class:`~fleet.errors.ConfigError` for an unknown backend or robot, a negative
    speed, a non-positive duration, or a bad ``api`` address."""

    #: The bus-loss watchdog of a connecting runner (``None`` for one that listens): it stops
    #: the local robots while the link is lost (``bus.link_timeout_s``, ``docs/faults.md``) and
    #: tells the coordinator which liveliness losses were this process's own.
    link: LinkWatch | None = None
    _link_reason = ""

    # long: one attribute per part of the run, each set once here
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
        tree_kind: str = TreeKind.PATROL,
        out: TextIO | None = None,
        listen: bool | None = None,
        traffic: bool | None = None,
        display: FleetDisplay | None = None,
        tree_file: str | None = None,
        state_dir: Path | None = None,
        api: str | None = None,
        secure: Secure | None = None,
        ticking: str = "event",
    ) -> None:
        if tree_file is not None:
            from nodes.xml_tree import check_tree_file

            tree_kind = check_tree_file(tree_file, config.sim.battery).task_kind
        self.tree_file = tree_file
        self.agent_names = check_args(config, backend, speed, duration, agents, ticking)
        self.scheduler: TickScheduler | None = None  # which trees tick (set up by run)
        self.config = config
        self.duration = duration
        self.speed = float(speed)
        self.endpoint = endpoint or config.endpoint
        self.backend_name = backend
        self.run_coordinator = coordinator
        self.out = out or sys.stdout
        self.live = self.out.isatty() if live is None else live
        self.tree_kind, self.listen, self.ticking = tree_kind, listen, ticking
        self.traffic = config.traffic.enabled if traffic is None else bool(traffic)
        try:
            TreeKind(tree_kind)
        except ValueError:
            raise ConfigError(
                str(config.path), "tree", f"unknown tree {tree_kind!r}; known: {', '.join(TreeKind)}"
            ) from None
        if self.traffic and tree_file is not None:
            if traffic:
                raise ConfigError(
                    str(config.path),
                    "traffic",
                    "traffic management drives the built-in task tree only, not an XML tree "
                    "(run the XML tree with --no-traffic)",
                )
            logger.warning("traffic management is off: the XML tree %s drives its own goals", tree_file)
            self.traffic = False
        self.display = display
        self.state_dir = state_dir
        self.api, self.secure = api, secure
        #: The task service and its faces (with the coordinator; set up by :meth:`run`).
        self.host: ServiceHost | None = None
        #: The e-stop latch below the trees (``fleet.runtime.latch``).
        self.latch = Latch()
        self._wakeup = threading.Event()
        #: The traffic policy when traffic management is on (set up by :meth:`run`).
        self.traffic_policy: ReservationTraffic | None = None
        self.stop_event = threading.Event()
        self._t0 = 0.0
        self._t_end: float | None = None
        self._wall = WallClock()
        self._wall0 = 0.0
        self.world: World | None = None
        self.agents: list[RobotAgent] = []
        self._observed: list[tuple[str, Observation]] = []  # the agents' since the last cycle
        #: Goal metrics of each local robot (by name), see :mod:`fleet.runtime.goal_log`.
        self.goal_logs: dict[str, GoalLog] = {}
        self.coordinator: Coordinator | None = None
        self.bus: StatusBus | None = None
        self.lease: CoordinatorLease | None = None  # held with the coordinator
        self.lease_watch: LeaseWatch | None = None  # followed by agents whose coordinator is elsewhere
        #: What this process saw of the fleet on the bus (latest statuses, bounded trajectories).
        self.bus_view = BusView()
        #: Called as ``observer(sim_time, runner)`` once per agent tick, after the agents and
        #: the coordinator cycle (e.g. to sample fleet metrics; see :mod:`fleet.loadtest`).
        self.observers: list[Callable[[float, FleetRunner], None]] = []
        #: Called with a line on each phase of the set-up (world, coordinator, agents every few
        #: wall seconds), which takes minutes for thousands of robots; ``None``: silent.
        self.on_setup: Callable[[str], None] | None = None

    # -- the run -------------------------------------------------------------------------

    def run(self) -> RunReport:
        """Run until ``duration`` simulated seconds passed or :meth:`stop` / Ctrl-C; always
        close the agents, the bus and the session. Returns the report (``interrupted`` set
        if it was stopped early). Raises :class:`~fleet.errors.BusError` if the session
        cannot be opened, :class:`~fleet.errors.BackendError` if the backend cannot be set up."""
        from fleet.bus.session import open_session

        factory = world_factory(self.backend_name)
        remote = bool(getattr(factory, "bus_elsewhere", False))
        listen = (not remote) if self.listen is None else self.listen
        self._wall0 = self._wall.now()
        session = open_session(self.endpoint, "router" if listen else "client", secure=self.secure)
        interrupted = False
        try:
            if not listen:
                from fleet.bus.link import LinkWatch

                self.link = LinkWatch(session, self.config.link_timeout_s)
            world = self._setup(factory, session)
            try:
                self._loop(world)
            except KeyboardInterrupt:
                interrupted = True
            except BackendError as e:  # e.g. the remote simulator went away: end, still report
                logger.warning("%s; ending the run", e)
                interrupted = True
            interrupted = interrupted or self.stop_event.is_set()
            logger.info(
                "%s: run %s at t=%.1f s",
                self.config.name,
                "stopped" if interrupted else "ended",
                world.clock.now(),
            )
            return self._report(world, self._wall.now() - self._wall0, interrupted)
        finally:
            self._close(session)

    def stop(self) -> None:
        """Ask the loop to end after the current iteration (thread-safe); a paced wait ends at once."""
        self.stop_event.set()
        self._wakeup.set()

    def wake(self) -> None:
        """A command arrived (thread-safe): run a coordinator cycle and tick the agents it gave
        orders to as soon as the loop can, not at the next scheduled tick."""
        self._wakeup.set()

    def _setup(self, factory: WorldFactory, session: zenoh.Session) -> World:
        """The bus, the world, the coordinator and the agents, on ``session``."""
        from fleet.bus.status_bus import StatusBus, process_batch_source

        specs = [self.config.robot(n) for n in self.agent_names]
        # batches are in no role of a secured bus (docs/security.md): its observers and
        # coordinators receive each robot's status on the robot's own key only
        batch = self.config.status_batch and len(specs) > 1 and self.secure is None
        # every status reaches the coordinator and the view by callback: no event queue (nothing
        # drains it, and at 10,000 robots it cost a quarter of the subscriber's time)
        source = process_batch_source() if batch else None
        self.bus = StatusBus(session, batch_source=source, max_events=0)
        self.bus.subscribe_statuses(self.bus_view.see)
        guard = self.bus.guard_orders(self.agent_names, wildcard=self.secure is None)  # counts early orders
        phase = SetupProgress(self.on_setup, self._wall)
        self.world = world = factory(self.config, specs, session)
        keep_state = getattr(world, "keep_state", None)
        if self.state_dir is not None and callable(keep_state):
            keep_state(self.state_dir)  # an in-process simulator resumes its robots, and keeps them
        phase.done(f"world: {len(specs)} robots")
        sim = getattr(world, "sim", None)
        self._world_latch = (
            WorldLatch(self.latch, sim) if sim is not None and hasattr(sim, "fault_of") else None
        )
        traced = [s.name for s in specs if world.trajectory(s.namespace) is not None]
        self.bus_view.skip_trajectories(traced)  # the world records these robots' trajectories
        from fleet.bus.lease import LeaseWatch, claim_robots

        self._agent_claims = claim_robots(session, self.agent_names, self.endpoint)
        if not self.run_coordinator and self.agent_names:
            self.lease_watch = LeaseWatch(session)
        if self.run_coordinator:
            self.coordinator = self._make_coordinator(world, self.bus)
            self.bus.declare_task_publishers(r.name for r in self.config.robots)  # not at first orders
            phase.done("coordinator" + (" and traffic manager" if self.traffic else ""))
        from nodes.blackboard import clear_robot_blackboards

        clear_robot_blackboards(s.namespace for s in specs)  # one pass, not one per agent
        self._charger_poses = tuple(c.pose for c in self.config.chargers)  # shared by the agents
        self.agents = []
        for spec in specs:
            self.agents.append(self._make_agent(spec.namespace, world, self.bus))
            phase.every(f"agents: {len(self.agents)} of {len(specs)}")
        phase.done(f"agents: {len(specs)}")
        backends, beat = [world.backend(s.namespace) for s in specs], self.config.heartbeat_s
        self.scheduler = TickScheduler(self.agents, backends, mode=self.ticking, heartbeat_s=beat)
        guard.undeclare()
        if self.coordinator is not None:
            self.coordinator.local_deliver = {a.name: a.deliver for a in self.agents}
            self.coordinator.local_grant_deliver = {a.name: a.deliver_grant for a in self.agents}
        self._start_service(session, self.bus)
        logger.info(
            "%s: backend %s ready, %d agents%s, traffic management %s, status on the bus %s",
            self.config.name,
            self.backend_name,
            len(self.agents),
            " + coordinator" if self.coordinator is not None else "",
            "on" if self.traffic else "off",
            f"at {self.config.status_hz:g} Hz" if self.config.status_hz else "every tick",
        )
        return world

    def _make_coordinator(self, world: World, bus: StatusBus) -> Coordinator:
        from fleet.coordination.coordinator import Coordinator
        from fleet.runtime.service_host import ServiceHost

        if self.traffic:
            from fleet.traffic.policy import traffic_from_config

            self.traffic_policy = traffic_from_config(self.config)
        token = self.secure.keyring().api_token() if self.secure is not None and self.api else None
        self.host = host = ServiceHost(self.config, world.clock, self.state_dir, self.api, api_token=token)
        self.lease = host.take_lease(bus.session, self.endpoint)
        coordinator = Coordinator(
            self.config,
            bus,
            world.clock,
            traffic=self.traffic_policy,
            local_robots=set(self.agent_names),
            task_kind=self.tree_kind,
            first_id=host.service.first_assignment_id,
            epoch=self.lease.epoch,
        )
        link = self.link
        if link is not None:
            coordinator.link_losses = lambda: link.losses
        host.service.attach(coordinator.state)
        return coordinator

    def _start_service(self, session: zenoh.Session, bus: StatusBus) -> None:
        """Control-state sinks (latch, agents, coordinator), the task service's faces."""
        host = self.host
        if host is None:  # no coordinator here: follow the one on the bus
            bus.subscribe_control(self.latch.follow)
            return
        svc = host.service
        svc.switch.add_sink(self.latch.follow)  # first: the world stops at its next step
        for a in self.agents:
            svc.switch.add_sink(a.set_control)
        if self.coordinator is not None:
            state = self.coordinator.state
            svc.switch.add_sink(lambda ctl: setattr(state, "halted", ctl.paused))
        svc.robot_source = self.records
        svc.on_input = self.wake
        svc.views["traffic_enabled"] = lambda: self.traffic
        if self.traffic_policy is not None:
            from fleet.runtime.service_host import traffic_view

            svc.views["traffic"] = traffic_view(self.traffic_policy)
        host.start(session, bus)
        api = f", API {host.api.url} (docs: {host.api.url}/docs)" if host.api is not None else ""
        if host.api is not None and host.api_token is not None and self.secure is not None:
            api += (
                f"; commands need the token: {host.api.url}/#token=<{self.secure.keyring().api_token_file}>"
            )
        book = host.state_dir if host.state_dir is not None else "in memory (no --state)"
        print(f"tasks: {book}{api}", file=self.out, flush=True)

    def _make_agent(self, namespace: str, world: World, bus: StatusBus) -> RobotAgent:
        from fleet.runtime.agent import RobotAgent
        from fleet.runtime.goal_log import GoalLog

        log = GoalLog(
            world.backend(namespace), world.clock, self.config.sim.model.max_linear_speed, self.config.roadmap
        )
        self.goal_logs[namespace.strip("/")] = log
        agent = RobotAgent(
            namespace,
            LatchedBackend(log, self.latch),
            world.clock,
            bus,
            # an XML tree reads the orders of its own kind; the built-in tree takes every kind
            tree_kind=TreeKind.TASKS if self.tree_file is None else self.tree_kind,
            battery_model=self.config.sim.battery,
            tick_hz=self.config.tick_hz,
            traffic=self.traffic,
            status_hz=self.config.status_hz,
            status_max_period_s=self.config.status_max_period_s,
            tree_file=self.tree_file,
            chargers=self._charger_poses,
            near_chargers=self.traffic and self.config.traffic.near_charger_trigger,
            leases=self.lease_watch.current if self.lease_watch is not None else None,
            clear_blackboard=False,  # _setup cleared every local namespace in one pass
        )
        if self.coordinator is not None:  # every period's status, as the coordinator reads it
            agent.observations = self._observed  # handed over in one call before each cycle
        return agent

    def _loop(self, world: World) -> None:
        clock = world.clock
        self._t0 = clock.now()
        ticks = TickSchedule(self._t0, 1.0 / self.config.tick_hz, self.duration)
        pacer = Pacer(clock, 0.0 if world.remote else self.speed, self._wall)
        display = self.display or default_display(self.out, self.live)
        next_show = self._wall.now() + display.interval_s
        try:
            while not self.stop_event.is_set():
                if self.link is not None:
                    self._watch_link(self.link)
                now = clock.now()
                if ticks.finished(now):
                    break
                if ticks.due(now):
                    self._tick(now)
                elif self._wakeup.is_set():
                    self._react()
                if self._world_latch is not None:
                    self._world_latch.apply()
                world.advance()
                self._pace(pacer)
                w = self._wall.now()
                if w >= next_show:
                    display.show(self.snapshot())
                    next_show = w + display.interval_s
        finally:
            self._t_end = clock.now()  # a remote world's clock runs on while the run closes
            display.close(self.snapshot())

    def _watch_link(self, link: LinkWatch) -> None:
        """The bus-loss watchdog: stop every local robot while the bus link is lost for longer
        than ``bus.link_timeout_s``, let them resume when it is back."""
        reason = link.check()
        if reason != self._link_reason:
            self._link_reason = reason
            for a in self.agents:
                a.set_link_lost(reason)

    def _pace(self, pacer: Pacer) -> None:
        """Wait for real time to catch up (``speed``), reacting to commands meanwhile."""
        woke: list[bool] = []

        def sleep(seconds: float) -> None:
            if self._wakeup.wait(seconds):
                woke.append(True)

        while not self.stop_event.is_set():
            woke.clear()
            pacer.wait(sleep)
            if not woke or self.stop_event.is_set():
                return
            self._react()

    def _react(self) -> None:
        """A command arrived: one coordinator cycle now, and a tick of every agent it (or the
        control state) gave something to do, so the order takes effect at the next step."""
        self._wakeup.clear()
        self._cycle()
        now = self.world.clock.now() if self.world is not None else 0.0
        for a in self.agents:
            if a.pending():
                a.period()
                if self.scheduler is not None:
                    self.scheduler.ticked(a, now)
        if self.bus is not None:
            self.bus.flush_statuses()

    def _tick(self, now: float) -> None:
        """One agent tick: every local agent (its tree when the scheduler says so), then the
        coordinator cycle, then the observers."""
        sched = self.scheduler
        due = sched.due(now).tolist() if sched is not None else [True] * len(self.agents)
        for a, tree in zip(self.agents, due, strict=True):
            a.period(tree)
            if a.tree_ticked and sched is not None:
                sched.ticked(a, now)
        if self.bus is not None:
            self.bus.flush_statuses()  # the statuses of this round, in batches when batching
        self._after_agents(now)

    def _cycle(self) -> None:
        """One coordinator cycle, on the local agents' observations since the last."""
        if self.coordinator is not None:
            self.coordinator.feed_observations(self._observed)
            self.coordinator.cycle()
        self._observed.clear()

    def _after_agents(self, now: float) -> None:
        """What follows the agents' tick: the coordinator cycle, the task service, the observers."""
        self._cycle()
        if self.host is not None:
            self.host.tick(now)
        for observe in self.observers:
            observe(now, self)

    # -- what the run looks like -----------------------------------------------------------

    def records(self) -> list[StatusRecord]:
        """The latest status record of every robot known here (local agents first)."""
        out: dict[str, StatusRecord] = {}
        for a in self.agents:
            if a.last_status is not None:
                out[a.name] = a.last_status
        for name, rec in self.bus_view.latest().items():
            out.setdefault(name, rec)
        return [out[k] for k in sorted(out, key=robot_sort_key)]

    def snapshot(self) -> FleetSnapshot:
        """The fleet now, for a display."""
        world = self.world
        recs = self.records()
        st = self.coordinator.state if self.coordinator is not None else None
        return FleetSnapshot(
            sim_time_s=world.clock.now() - self._t0 if world is not None else 0.0,
            wall_s=self._wall.now() - self._wall0,
            records=recs,
            alive=self.bus.alive() if self.coordinator is not None and self.bus is not None else None,
            duration_s=self.duration,
            laps=st.laps_completed() if st is not None else None,
            charging=sum(1 for r in recs if r.mode == Mode.CHARGING),
            # a remote simulator's clock, or one resumed from --state, ran before this process
            clock_s=world.clock.now() if world is not None and (world.remote or self._t0 > 0) else None,
        )

    def _report(self, world: World, wall_s: float, interrupted: bool) -> RunReport:
        for log in self.goal_logs.values():
            log.close()
        builder = ReportBuilder(
            self.config, self.backend_name, self.speed, self.agent_names, t0=self._t0, t_end=self._t_end
        )
        return builder.build(
            world,
            {r.robot: r for r in self.records()},
            wall_s=wall_s,
            interrupted=interrupted,
            state=self.coordinator.state if self.coordinator is not None else None,
            traffic=self.traffic_policy,
            charges={a.name: a.charges for a in self.agents},
            goals={name: log.metrics for name, log in self.goal_logs.items()},
            safety_stops={a.name: a.watchdog.trips for a in self.agents},
            min_battery={a.name: a.min_battery for a in self.agents},
            mode_ticks=sum_counts(a.mode_ticks for a in self.agents),
            bus_trajectory=self.bus_view.trajectory,
            malformed=self.malformed(),
            rejected=self.rejected(),
            tasks=self.host.task_summary() if self.host is not None else None,
            control_events=self.host.control_events() if self.host is not None else (),
        )

    def malformed(self) -> int:
        """Payloads this process dropped unparsed: on the status bus, from a remote simulator
        (clock, navigation states) and on the task service's bus face."""
        n = self.bus.malformed if self.bus is not None else 0
        world_count = getattr(self.world, "malformed", None)
        if callable(world_count):
            n += int(world_count())
        if self.host is not None:
            n += self.host.service.bad_requests
            n += self.host.face.malformed if self.host.face is not None else 0
        return n

    def rejected(self) -> int:
        """Well-formed messages this process ignored: orders and grants not from the live
        coordinator (its agents' gates), clock and navigation states not from a live simulator."""
        n = sum(a.gate.rejected_total for a in self.agents if a.gate is not None)
        world_count = getattr(self.world, "rejected", None)
        return n + (int(world_count()) if callable(world_count) else 0)

    def collision_points(self) -> list[tuple[float, float]]:
        """Where robots touched, ``(x, y)`` in the ``map`` frame (empty if the world cannot see)."""
        return self.world.collision_points() if self.world is not None else []

    def _close(self, session: zenoh.Session) -> None:
        if self.host is not None:
            close_logged(self.host.close, "closing the task service", logger)
        for a in self.agents:
            close_logged(a.close, f"closing agent {a.name}", logger)
        if self.lease_watch is not None:
            close_logged(self.lease_watch.close, "closing the lease watch", logger)
        if self.lease is not None:
            close_logged(self.lease.release, "releasing the coordinator lease", logger)
        if self.world is not None:
            close_logged(self.world.close, "closing the backend", logger)
        if self.bus is not None:
            close_logged(self.bus.close, "closing the bus", logger)
        try:
            session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves Session.close unannotated
        except Exception as e:  # noqa: BLE001 - already closed by the bus
            logger.debug("closing the session: %s", e)


__all__ = ["FleetRunner"]
