"""The main process of ``fleet loadtest --workers K``: simulator, coordinator and traffic
management here, the agents in ``K`` worker processes, in lockstep (:mod:`fleet.loadtest.lockstep`).

:class:`DistributedRunner` is a :class:`~fleet.runtime.runner.FleetRunner` without local
agents: at each agent tick it sends every worker its snapshot, serves the workers' goal calls
on the simulator while they tick, takes their status records and feeds them to the
coordinator in robot order, exactly where a one-process run's agents would. The coordinator
treats every robot as local (orders and grants go out with the next tick, not over the bus).

Processes: ``local_workers`` of the ``K`` workers are started here (``python -m
fleet.loadtest.worker``, same interpreter); the rest must be started by hand, on this machine or
others, against this process's endpoint. The run starts when all ``K`` said they are ready
(progress lines meanwhile; :class:`~fleet.errors.BackendError` after ``ready_timeout_s``). A
worker process that exits, or a tick not answered within ``tick_timeout_s``, ends the run
(reported as interrupted). On a secured bus (``secure``) the workers get ``--secure DIR`` and
connect as the key directory's ``worker`` identity. On every exit path (the end, Ctrl-C, an error) the workers are told
to stop, then terminated, then killed, and waited for."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TextIO, cast

import zenoh

from fleet.bus.session import Declaration, undeclare_all
from fleet.config.model import FleetConfig
from fleet.errors import BackendError
from fleet.loadtest.lockstep import (
    AgentStats,
    DoneMsg,
    NavCall,
    NavReply,
    RunSpec,
    TickMsg,
    decoder,
    done_key,
    encode,
    nav_key,
    spec_key,
    tick_key,
)
from fleet.messages import Grant, StatusRecord, TaskMessage
from fleet.messages.nav import goal_of
from fleet.runtime.runner import FleetRunner

if TYPE_CHECKING:
    from fleet.navigation import NavigationBackend
    from fleet.runtime.agent import RobotAgent
    from fleet.runtime.report import RunReport
    from fleet.runtime.worlds import World, WorldFactory
    from fleet.types import GoalState

logger = logging.getLogger(__name__)

#: Wall seconds to wait for every worker to be ready.
READY_TIMEOUT_S = 300.0
#: Wall seconds to wait for a worker's answer to one tick (a tick of many agents with many
#: goal calls can take minutes on a saturated machine; a local worker that dies is noticed
#: at once).
TICK_TIMEOUT_S = 600.0
#: A tick not answered within this many wall seconds is sent again.
TICK_RESEND_S = 5.0
#: Wall seconds the workers get to answer the last (``end``) tick.
END_TIMEOUT_S = 15.0

_done = decoder(DoneMsg)
_call = decoder(NavCall)


def assign(names: list[str], workers: int) -> list[list[str]]:
    """Contiguous slices of ``names`` (in order) for ``workers`` workers, sizes differing by at
    most one."""
    out, first = [], 0
    for i in range(workers):
        n = len(names) // workers + (1 if i < len(names) % workers else 0)
        out.append(names[first : first + n])
        first += n
    return out


class RemoteAgent:
    """What the runner keeps of an agent that runs in a worker: its latest status record and,
    at the end, the statistics the report needs. It has no order gate: its orders travel in
    the lockstep ticks, not on the bus."""

    gate = None

    def __init__(self, name: str) -> None:
        self.name = name
        self.last_status: StatusRecord | None = None
        self.charges = 0
        self.min_battery = 1.0
        self.mode_ticks: dict[str, int] = {}
        self.watchdog = _Trips()

    def pending(self) -> bool:
        return False

    def close(self) -> None:
        return None

    def take(self, stats: AgentStats) -> None:
        self.charges, self.min_battery = stats.charges, stats.min_battery
        self.mode_ticks, self.watchdog.trips = dict(stats.mode_ticks), stats.safety_stops


class _Trips:
    trips = 0


class DistributedRunner(FleetRunner):
    """A load-test run with its agents in ``spec.assignment``'s workers (see the module
    docstring). Arguments as :class:`FleetRunner`'s, plus the run's ``spec``, how many workers
    to start here (``local_workers``, default all) and where their output goes (``log_dir``)."""

    def __init__(
        self,
        config: FleetConfig,
        spec: RunSpec,
        *,
        local_workers: int | None = None,
        log_dir: Path | None = None,
        progress: Callable[[str], None] | None = None,
        run_id: str = "main",
        **kw: object,
    ) -> None:
        super().__init__(config, agents=[], **kw)  # type: ignore[arg-type]
        self.spec = spec
        self.run_id = run_id
        self.workers = len(spec.assignment)
        self.local_workers = self.workers if local_workers is None else local_workers
        self.log_dir = log_dir
        self.progress = progress or (lambda line: None)
        self.procs: list[subprocess.Popen[bytes]] = []
        self._logs: list[TextIO] = []
        self._decls: list[Declaration] = []
        self._pubs: list[zenoh.Publisher] = []
        self._backends: dict[str, NavigationBackend] = {}
        self._ns: dict[str, str] = {}
        self._remote: dict[str, RemoteAgent] = {}
        self._orders: dict[str, list[bytes]] = {}
        self._grants: dict[str, list[bytes]] = {}
        self._answers: dict[int, DoneMsg] = {}
        self._watch: dict[int, list[str]] = {i: [] for i in range(self.workers)}
        self._cv = threading.Condition()
        self._nav_lock = threading.Lock()
        self._served: dict[int, tuple[int, bytes]] = {}  # worker -> its last call and answer
        self._k = 0
        self._session: zenoh.Session | None = None
        self.calls = 0
        self._stopped = False

    # -- setup -------------------------------------------------------------------------------

    def _setup(self, factory: WorldFactory, session: zenoh.Session) -> World:
        world = super()._setup(factory, session)  # no local agents: the world and the coordinator
        from fleet.runtime.goal_log import GoalLog
        from fleet.runtime.latch import LatchedBackend

        names = [n for part in self.spec.assignment for n in part]
        for name in names:
            ns = self._ns[name] = self.config.robot(name).namespace
            log = GoalLog(
                world.backend(ns), world.clock, self.config.sim.model.max_linear_speed, self.config.roadmap
            )
            self.goal_logs[name] = log
            self._backends[ns] = LatchedBackend(log, self.latch)
            self._remote[name] = RemoteAgent(name)
            self._orders[name], self._grants[name] = [], []
        self.agent_names = names  # the report covers every robot
        self.bus_view.skip_trajectories(names)  # the simulator here records them
        self.agents = cast("list[RobotAgent]", list(self._remote.values()))
        if self.coordinator is not None:
            self.coordinator.local_robots = set(names)
            self.coordinator.local_deliver = {n: self._order_sink(n) for n in names}
            self.coordinator.local_grant_deliver = {n: self._grant_sink(n) for n in names}
        self._session = session
        self._decls += [
            session.declare_queryable(
                spec_key(self.run_id), lambda q: q.reply(q.key_expr, encode(self.spec))
            ),
            session.declare_queryable(nav_key(self.run_id), self._on_call),
        ]
        self._decls += [
            session.declare_subscriber(done_key(self.run_id, i), self._on_done) for i in range(self.workers)
        ]
        # congestion control drop, and a tick not answered in TICK_RESEND_S is sent again: with
        # block, a put of a large tick once stalled for minutes on a saturated machine
        self._pubs += [
            session.declare_publisher(
                tick_key(self.run_id, i), congestion_control=zenoh.CongestionControl.DROP
            )
            for i in range(self.workers)
        ]
        self._start_workers()
        self._wait_ready()
        return world

    def _order_sink(self, name: str) -> Callable[[TaskMessage], None]:
        return lambda msg: self._orders[name].append(msg.to_json())

    def _grant_sink(self, name: str) -> Callable[[Grant], None]:
        return lambda g: self._grants[name].append(g.to_json())

    def _start_workers(self) -> None:
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
        for i in range(self.local_workers):
            cmd = [
                sys.executable,
                "-m",
                "fleet.loadtest.worker",
                "--endpoint",
                self.endpoint,
                "--index",
                str(i),
            ]
            cmd += ["--run", self.run_id, "--parent", str(os.getpid()), *self._secure_args()]
            out: TextIO | int = subprocess.DEVNULL
            if self.log_dir is not None:
                self.log_dir.mkdir(parents=True, exist_ok=True)
                out = open(self.log_dir / f"worker{i}.log", "w")  # noqa: SIM115 - closed in _stop_workers
                self._logs.append(out)
                cmd += ["--out", str(self.log_dir / f"worker{i}")]
            self.procs.append(subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env))
        if self.local_workers < self.workers:
            self.progress(
                f"start workers {self.local_workers}..{self.workers - 1} yourself: python -m fleet.loadtest.worker "
                f"--endpoint {self.endpoint} --index I{' '.join(['', *self._secure_args()])}"
            )

    def _secure_args(self) -> list[str]:
        """A worker's ``--secure DIR`` on a secured bus (it connects as ``worker``)."""
        return [] if self.secure is None else ["--secure", str(self.secure.keys)]

    def _wait_ready(self) -> None:
        end = time.monotonic() + READY_TIMEOUT_S
        shown = -1
        while True:
            with self._cv:
                ready = sum(1 for d in self._answers.values() if d.k == -1)
                if ready == self.workers:
                    self._answers.clear()
                    break
                self._cv.wait(0.5)
            self._check_procs()
            if ready != shown:
                self.progress(f"workers ready: {ready}/{self.workers}")
                shown = ready
            if time.monotonic() > end:
                raise BackendError(
                    f"only {ready} of {self.workers} load-test workers ready after {READY_TIMEOUT_S:g} s"
                )
        self.progress(f"workers ready: {self.workers}/{self.workers}; running")

    def _check_procs(self) -> None:
        for i, p in enumerate(self.procs):
            code = p.poll()
            if code is not None:
                raise BackendError(f"load-test worker {i} (pid {p.pid}) exited with code {code}")

    # -- the workers' messages (Zenoh threads) --------------------------------------------------

    def _on_done(self, sample: zenoh.Sample) -> None:
        try:
            msg = _done(sample.payload.to_bytes())
        except ValueError as e:
            logger.warning("malformed answer from a load-test worker: %s", e)
            return
        with self._cv:
            if msg.k == -1 and msg.worker in self._answers:
                return
            self._answers[msg.worker] = msg
            self._cv.notify_all()

    def _on_call(self, query: zenoh.Query) -> None:
        try:
            call = _call(query.payload.to_bytes() if query.payload is not None else b"")
            backend = self._backends[call.namespace]
            with self._nav_lock:
                done = self._served.get(call.worker)
                if done is not None and done[0] == call.call:
                    data = done[1]  # asked again: the same answer, not a second goal
                else:
                    data = encode(self._serve(call, backend))
                    self._served[call.worker] = (call.call, data)
        except Exception as e:  # noqa: BLE001 - answer with the reason, never raise into Zenoh
            logger.warning("load-test goal call failed: %r", e)
            query.reply_err(f"the main process could not serve the call: {e!r}".encode())
            return
        query.reply(query.key_expr, data)

    def _serve(self, call: NavCall, backend: NavigationBackend) -> NavReply:
        self.calls += 1
        gid, err = call.goal_id, ""
        if call.op == "send" and call.goal is not None:
            try:
                gid = backend.send_goal(goal_of(call.goal))
            except BackendError as e:
                err = str(e)
        elif call.op == "cancel":
            backend.cancel_goal(gid)
        state = None
        if not err:
            try:
                state = backend.goal_state(gid)
            except KeyError:
                err = f"unknown goal {gid!r}"
        return NavReply(gid, state, backend.robot_state(), err)

    # -- the lockstep tick -------------------------------------------------------------------

    def _tick(self, now: float) -> None:
        self._k += 1
        self._round(TickMsg(self._k, now, [], [], [], []))
        for i in range(self.workers):
            for rec in self._answers[i].records:
                self._remote[rec.robot].last_status = rec
                if self.coordinator is not None:
                    self.coordinator.feed_local(rec)
            self._watch[i] = self._answers[i].watch
        self._after_agents(now)

    def _round(self, base: TickMsg, timeout_s: float = TICK_TIMEOUT_S) -> None:
        """Send every worker its tick, wait for every answer (in ``self._answers``)."""
        with self._cv:
            self._answers.clear()
        # built first: the workers' calls then change the simulator while nothing here reads it
        data = [encode(base if base.end else self._tick_msg(base, i)) for i in range(self.workers)]
        for pub, d in zip(self._pubs, data, strict=True):
            pub.put(d)
        end = time.monotonic() + timeout_s
        resend = time.monotonic() + TICK_RESEND_S
        while True:
            with self._cv:
                missing = [
                    i
                    for i in range(self.workers)
                    if not (i in self._answers and self._answers[i].k == base.k)
                ]
                if not missing:
                    return
                self._cv.wait(0.2)
            if time.monotonic() > resend:  # a tick or an answer may have been dropped: ask again
                for i in missing:  # (a worker answers a tick it already did from its last answer)
                    self._pubs[i].put(data[i])
                resend = time.monotonic() + TICK_RESEND_S
            if not base.end:  # a worker that answered the end may already have exited
                self._check_procs()
            if self.stop_event.is_set() and not base.end:
                raise KeyboardInterrupt
            if time.monotonic() > end:
                missing = [i for i in range(self.workers) if i not in self._answers]
                raise BackendError(
                    f"load-test workers {missing} did not answer tick {base.k} in {timeout_s:g} s"
                )

    def _tick_msg(self, base: TickMsg, worker: int) -> TickMsg:
        """Worker ``worker``'s tick: its robots' states, its watched goals, its new orders."""
        names = self.spec.assignment[worker]
        msg = TickMsg(
            base.k,
            base.t,
            [self._backends[self._ns[n]].robot_state() for n in names],
            self._goal_states(worker),
            [o for n in names for o in self._orders[n]],
            [g for n in names for g in self._grants[n]],
        )
        for n in names:
            self._orders[n].clear()
            self._grants[n].clear()
        return msg

    def _goal_states(self, worker: int) -> list[tuple[str, GoalState]]:
        out: list[tuple[str, GoalState]] = []
        for gid in self._watch[worker]:
            ns = gid.split("#", 1)[0]
            backend = self._backends.get(ns)
            if backend is None:
                continue
            try:
                out.append((gid, backend.goal_state(gid)))
            except KeyError:
                continue
        return out

    # -- the end -----------------------------------------------------------------------------

    def _report(self, world: World, wall_s: float, interrupted: bool) -> RunReport:
        self._stop_workers()  # their agents' statistics go into the report
        return super()._report(world, wall_s, interrupted)

    def _close(self, session: zenoh.Session) -> None:
        try:
            self._stop_workers()
        finally:
            undeclare_all([*self._decls, *self._pubs])
            super()._close(session)

    def _stop_workers(self) -> None:
        """Ask the workers to end (their agents' statistics come back), then make sure every
        local worker process is gone (idempotent)."""
        if self._stopped:
            return
        self._stopped = True
        if self._session is not None and all(p.poll() is None for p in self.procs):
            try:
                self._round(TickMsg(self._k + 1, 0.0, [], [], [], [], end=True), timeout_s=END_TIMEOUT_S)
                for i in range(self.workers):
                    for st in self._answers[i].stats:
                        self._remote[st.robot].take(st)
            except (BackendError, KeyboardInterrupt) as e:
                logger.warning("the load-test workers did not end cleanly: %s", e)
        self.progress(f"workers stopped after {self._k} ticks; {self.calls} goal calls served")
        for p in self.procs:
            try:
                p.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                p.terminate()
                try:
                    p.wait(timeout=5.0)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        for f in self._logs:
            f.close()
