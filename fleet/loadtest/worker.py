"""A load test's agent worker: ``python -m fleet.loadtest.worker --endpoint EP --index I``.

Connects (Zenoh client) to the router of a ``fleet loadtest --workers K`` main process, asks it
for the run (:class:`~fleet.loadtest.lockstep.RunSpec`), generates the same warehouse from the
same arguments (into ``--out``, default a temporary directory), builds the agents of the
robots assigned to worker ``I`` and ticks them in lockstep with the main process
(:mod:`fleet.loadtest.lockstep`) until it says ``end`` or stops answering. The main process
starts its local workers itself; start this command by hand on other machines (``--index`` of
the workers the main process was told not to start, ``docs/performance.md``). On a secured
bus (``--secure DIR``) the worker connects as the identity ``worker`` of the key directory
(``--identity`` to choose another), which may take part in the lockstep protocol and publish its
robots' statuses and liveliness, nothing else (``docs/security.md``); it then publishes each
robot's status on the robot's own key (status batches are in no role).

Exit codes: 0 the run ended, 1 the main process went away or sent something malformed, 2 bad
usage or no router, 130 interrupted."""

from __future__ import annotations

import argparse
import logging
import os
import queue
import socket
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import msgspec
import zenoh

from fleet.bus.session import Declaration, Secure, checked_secure, open_session, undeclare_all
from fleet.bus.status_bus import BusHandle, StatusBus
from fleet.errors import BackendError, BusError, FleetError
from fleet.loadtest.lockstep import (
    AgentStats,
    DoneMsg,
    MirrorBackend,
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
from fleet.runtime.process_exit import exit_now

logger = logging.getLogger(__name__)

#: A worker that hears nothing from the main process for this long after its last answer
#: (wall s) gives up.
IDLE_S = 600.0
#: How long a worker waits for the main process's run description (wall s).
SPEC_WAIT_S = 60.0
#: A goal call not answered within this long (wall s) ends the worker.
CALL_TIMEOUT_S = 300.0
#: A goal call not answered within this long (wall s) is asked again.
CALL_RETRY_S = 5.0

_spec = decoder(RunSpec)
_tick = decoder(TickMsg)
_reply = decoder(NavReply)


class _Quiet:
    """A bus handle that declares nothing."""

    def undeclare(self) -> None:
        return None


class WorkerBus:
    """The agents' bus in a worker: statuses and liveliness on the real bus; orders and grants
    come only with the ticks (in the coordinator's order), so the bus copies are not taken."""

    def __init__(self, bus: StatusBus) -> None:
        self.bus = bus

    def publish_status(self, rec: StatusRecord) -> None:
        self.bus.publish_status(rec)

    def subscribe_tasks(self, robot: str, callback: object) -> _Quiet:
        return _Quiet()

    def subscribe_grants(self, robot: str, callback: object) -> _Quiet:
        return _Quiet()

    def declare_alive(self, robot: str) -> BusHandle:
        return self.bus.declare_alive(robot)


def fetch_spec(session: zenoh.Session, run: str, timeout_s: float = SPEC_WAIT_S) -> RunSpec:
    """Ask the main process for the run until it answers; BusError after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for reply in session.get(spec_key(run), timeout=2.0):
            if reply.ok is not None:
                return _spec(reply.ok.payload.to_bytes())
        time.sleep(0.2)
    raise BusError(
        f"no `fleet loadtest --workers` main process answered on {spec_key(run)} within {timeout_s:g} s"
    )


def _caller(session: zenoh.Session, run: str, worker: int) -> Callable[[NavCall], NavReply]:
    key = nav_key(run)
    count = 0

    def call(c: NavCall) -> NavReply:
        nonlocal count
        count += 1
        data = encode(msgspec.structs.replace(c, worker=worker, call=count))
        why = f"no answer within {CALL_TIMEOUT_S:g} s"
        end = time.monotonic() + CALL_TIMEOUT_S
        while time.monotonic() < end:  # ask again if an answer is late: the main process
            for reply in session.get(key, payload=data, timeout=CALL_RETRY_S):  # serves it once
                if reply.ok is not None:
                    return _reply(reply.ok.payload.to_bytes())
                if reply.err is not None:
                    why = reply.err.payload.to_bytes().decode("utf-8", "replace")
                    if "could not serve" in why:
                        raise BackendError(f"the load test's main process failed a {c.op} call: {why}")
        raise BackendError(
            f"the load test's main process did not serve a {c.op} call for {c.namespace}: {why}"
        )

    return call


# long: the worker's whole life, setup to the final answer, reads best in one piece
def run_worker(
    endpoint: str,
    index: int,
    *,
    run: str = "main",
    out_dir: str | Path | None = None,
    parent: int | None = None,
    secure: Secure | None = None,
) -> int:
    """Run worker ``index`` of the load test on ``endpoint`` (see the module docstring);
    ``parent``: the pid of the main process that started it (it exits when that one is gone);
    ``secure``: connect to a secured bus with that identity."""
    from fleet.clock import SimClock
    from fleet.loadtest.run import prepare_config
    from fleet.runtime.agent import RobotAgent
    from fleet.types import TreeKind

    session = open_session(endpoint, "client", connect_timeout_s=10.0, secure=secure)
    inbox: queue.Queue[bytes] = queue.Queue()
    sub: Declaration = session.declare_subscriber(
        tick_key(run, index), lambda s: inbox.put(s.payload.to_bytes())
    )
    bus = StatusBus(session, batch_source=None if secure else f"{_host()}-{os.getpid()}-w{index}")
    agents: list[RobotAgent] = []
    tmp: tempfile.TemporaryDirectory[str] | None = None
    try:
        spec = fetch_spec(session, run)
        if not 0 <= index < len(spec.assignment):
            raise BusError(f"worker index {index} out of range: the run has {len(spec.assignment)} workers")
        if out_dir is None:
            tmp = tempfile.TemporaryDirectory(prefix=f"fleet-worker{index}-")
            out = Path(tmp.name)
        else:
            out = Path(out_dir)
        cfg = prepare_config(
            spec.robots,
            out,
            tick_hz=spec.tick_hz,
            status_hz=spec.status_hz,
            step_s=spec.step_s,
            route_copies=spec.route_copies,
            seed=spec.seed,
        )
        cfg.status_max_period_s = spec.status_max_period_s
        call = _caller(session, run, index)
        clock = SimClock()
        wbus = WorkerBus(bus)
        mirrors: list[MirrorBackend] = []
        chargers = tuple(c.pose for c in cfg.chargers)  # one tuple: the agents share its arrays
        for name in spec.assignment[index]:
            ns = cfg.robot(name).namespace
            mirror = MirrorBackend(ns, call)
            mirrors.append(mirror)
            agents.append(
                RobotAgent(
                    ns,
                    mirror,
                    clock,
                    wbus,
                    tree_kind=TreeKind.TASKS,
                    battery_model=cfg.sim.battery,
                    tick_hz=cfg.tick_hz,
                    traffic=spec.traffic,
                    status_hz=cfg.status_hz,
                    status_max_period_s=cfg.status_max_period_s,
                    chargers=chargers,
                    near_chargers=spec.traffic and cfg.traffic.near_charger_trigger,
                )
            )
        by_name = {a.name: a for a in agents}
        answer = bus.session.declare_publisher(
            done_key(run, index), congestion_control=zenoh.CongestionControl.DROP
        )
        logger.info("worker %d: %d agents ready", index, len(agents))
        ready = encode(DoneMsg(index, -1, [], []))
        answer.put(ready)
        started, last = False, time.monotonic()
        done_k, sent = 0, None  # the last tick answered, and the answer
        while True:
            try:
                data = inbox.get(timeout=0.5)
            except queue.Empty:
                if not started:
                    answer.put(ready)  # the main process may have missed it
                if parent is not None and os.getppid() != parent:
                    raise BusError("the main process that started this worker is gone") from None
                if time.monotonic() - last > IDLE_S:
                    raise BusError(f"no tick from the main process for {IDLE_S:g} s") from None
                continue
            started, last = True, time.monotonic()
            msg = _tick(data)
            if msg.k <= done_k:  # asked again (our answer was dropped): the same answer
                if msg.k == done_k and sent is not None:
                    answer.put(sent)
                continue
            if msg.end:
                for m in mirrors:
                    m.detach()
                stats = [
                    AgentStats(a.name, a.charges, a.min_battery, dict(a.mode_ticks), a.watchdog.trips)
                    for a in agents
                ]
                answer.put(encode(DoneMsg(index, msg.k, [], [], stats)))
                return 0
            clock.set(msg.t)
            goals = dict(msg.goals)
            for mirror, st in zip(mirrors, msg.states, strict=True):
                mirror.update(st, goals)
            for o in msg.orders:
                t = TaskMessage.from_json(o)
                if t.robot in by_name:
                    by_name[t.robot].deliver(t)
            for g in msg.grants:
                grant = Grant.from_json(g)
                if grant.robot in by_name:
                    by_name[grant.robot].deliver_grant(grant)
            records = [a.tick() for a in agents]
            bus.flush_statuses()
            watch = [gid for m in mirrors for gid in m.watch()]
            sent, done_k = encode(DoneMsg(index, msg.k, records, watch)), msg.k
            answer.put(sent)
            last = time.monotonic()  # idle from the answer on: a tick may take long under load
    finally:
        for a in agents:
            try:
                a.close()
            except Exception as e:  # noqa: BLE001 - keep closing
                logger.debug("closing %s: %s", a.name, e)
        undeclare_all([sub])
        bus.shutdown()
        if tmp is not None:
            tmp.cleanup()


def _host() -> str:
    return "".join(c if c.isalnum() or c in "_.-" else "_" for c in socket.gethostname()) or "host"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m fleet.loadtest.worker",
        description="Run one agent worker of a `fleet loadtest --workers K` run (see docs/performance.md).",
    )
    ap.add_argument(
        "--endpoint", required=True, help="the main process's Zenoh endpoint, e.g. tcp/10.0.0.5:7447"
    )
    ap.add_argument("--index", type=int, required=True, help="this worker's index, 0 .. K-1")
    ap.add_argument("--run", default="main", help=argparse.SUPPRESS)
    ap.add_argument("--parent", type=int, help=argparse.SUPPRESS)
    ap.add_argument(
        "--out", type=Path, help="where to generate the warehouse (default: a temporary directory)"
    )
    ap.add_argument(
        "--secure", type=Path, metavar="DIR", help="secured bus: the key directory of the main process"
    )
    ap.add_argument(
        "--identity", default="worker", help="the identity of DIR to connect as (default: worker)"
    )
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        secure = checked_secure(a.secure, a.identity) if a.secure is not None else None
    except BusError as e:  # bad usage: a path that is no key directory (or lacks the identity)
        print(f"fleet loadtest worker {a.index}: {e}", file=sys.stderr)
        return 2
    try:
        return run_worker(a.endpoint, a.index, run=a.run, out_dir=a.out, parent=a.parent, secure=secure)
    except KeyboardInterrupt:
        return 130
    except FleetError as e:
        print(f"fleet loadtest worker {a.index}: {e}", file=sys.stderr)
        return 1 if isinstance(e, BackendError | BusError) else 2
    except ValueError as e:
        print(
            f"fleet loadtest worker {a.index}: malformed message from the main process: {e}", file=sys.stderr
        )
        return 1


if __name__ == "__main__":
    exit_now(main())  # everything is closed: skip the interpreter's slow finalization
