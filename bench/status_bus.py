"""Issue 12 target 4: N robots' statuses on the bus, loss per robot and latency, through a router.

Topology (loopback, scouting off, ``tcp/127.0.0.1:<free port>``): this process opens the
**router** session and the coordinator's kind of subscriber, a
:class:`~fleet.bus.status_bus.StatusBus` with ``subscribe_statuses(callback)`` (every record
decoded and validated as the coordinator's are). ``--workers`` child processes (Zenoh clients,
as ``fleet loadtest --workers K`` runs its agents) each own a share of the ``--robots`` robots and
publish every robot's record once per ``1 / --hz`` s through ``StatusBus.publish_status``, then
``flush_statuses()`` at the end of the round, exactly as the runner does after a round of agent
ticks: with ``--mode batch`` (a process with many agents, ``bus.status_batch``, the default)
records go out as batches on ``fleet/batch/<worker>/status``; ``--mode single`` one put per
record on ``fleet/<robot>/status``. Every robot's record changes every period (the worst case
of publishing on change).

``--spread F``: a worker builds its robots' records over the first ``F`` of each period, one
after another, as agents ticking in turn do (0: all at once, the heaviest burst for the
subscriber; 0.8, the default: as a worker whose agents fill 80 % of the period). The workers'
periods are offset by ``1 / workers`` of a period, as independent processes' are. Before the
clock starts each worker warms its link with a few rounds of an ignored robot's records.

Accounting: every record carries its robot's sequence number (``seq``, 1, 2, ...) and is
stamped (``t``) with the wall time at which it was *built*, so its latency is everything after:
the wait in the sender's batch, the put, the router, the subscriber's decoding and callback
(receive time minus ``t``; one machine, one clock). :class:`SeqTally` counts per robot the
records received, the gaps in the sequence (lost), those that came late (out of order) or
twice. Prints, per run: sent, received, lost, out of order, duplicates, latency
p50 / p95 / p99 / max, malformed batches counted against those injected by worker 0, the
workers' lag behind schedule and CPU per record, the subscriber process's CPU. Exit 1 if any
record was lost, late or doubled, or malformed batches were not counted.

    python bench/status_bus.py --robots 1000,5000,10000 --workers 1,2,4 --hz 10 --seconds 10
    python bench/status_bus.py --robots 10000 --workers 4 --hz 10 --spread 0   # one burst
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import zenoh

import fleet
import fleet.bus.status_bus as status_bus_module
from fleet.bus.keys import status_batch_key, status_key
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord
from fleet.messages.status_batch import MAX_BATCH_RECORDS, decode_batch, encode_batch

#: The batch delay of this checkout's StatusBus (none in one from before it; --cpu-per-record
#: can then still measure that checkout: PYTHONPATH=<checkout> python bench/status_bus.py ...).
MAX_BATCH_DELAY_S: float | None = getattr(status_bus_module, "MAX_BATCH_DELAY_S", None)

#: Wall seconds the subscriber waits for the last records after the workers finished.
DRAIN_S = 10.0
#: A pacing worker sleeps when it is this far (s) ahead of its schedule: records leave in clumps
#: of at most 1 ms of agents, not one sleep per robot (10,000 sleeps per second per worker).
PACE_S = 0.001
#: Wall seconds allowed to a worker to connect and see the subscriber.
CONNECT_S = 60.0
#: Before the clock starts each worker sends this many rounds of records of a robot named
#: WARM_ROBOT<index> (ignored by the count): on a fresh Zenoh link the first two large messages
#: took 10-40 ms where the next took 0.3 (plain Zenoh, 50-120 kB), a one-off per process that
#: would otherwise be a whole round of records, 1 % of a 100-round run.
WARM_ROUNDS = 3
WARM_ROBOT = "warmup"


def record(robot: str, seq: int, t: float) -> StatusRecord:
    """A typical patrol status record (about 230 bytes) of ``robot``: number ``seq``, built at
    wall time ``t``."""
    return StatusRecord(
        robot=robot,
        ns=f"/{robot}",
        t=t,
        pose=(12.25, 7.5, 1.5708),
        battery=0.83,
        charging=False,
        stuck=False,
        bt="RUNNING",
        leaf="FollowRoute",
        mode="patrol",
        task_id="p-0003",
        laps=2,
        progress=0.4,
        distance_m=123.4,
        collisions=0,
        seq=seq,
    )


@dataclass
class SeqTally:
    """Per-robot sequence accounting of received records (``seq`` 1, 2, ... per robot).

    ``take`` is called for every record received, in arrival order. A record whose ``seq``
    skips ahead opens a gap (the skipped numbers are *missing*); one that fills a missing number
    later counts as ``late``; one already seen (or below the first seen) as ``duplicate``.
    :meth:`lost` adds the numbers still missing and those never received after each robot's
    last (its tail, against what the sender says it sent). Latencies in seconds."""

    received: int = 0
    late: int = 0
    duplicate: int = 0
    last: dict[str, int] = field(default_factory=dict)
    missing: dict[str, set[int]] = field(default_factory=dict)
    latencies: list[float] = field(default_factory=list)

    def take(self, robot: str, seq: int, latency_s: float) -> None:
        self.received += 1
        self.latencies.append(latency_s)
        last = self.last.get(robot, 0)
        if seq == last + 1:
            self.last[robot] = seq
        elif seq > last:
            self.missing.setdefault(robot, set()).update(range(last + 1, seq))
            self.last[robot] = seq
        elif seq in self.missing.get(robot, ()):
            self.missing[robot].discard(seq)
            self.late += 1
        else:
            self.duplicate += 1

    def gaps(self) -> int:
        """Numbers skipped by a later record and still missing."""
        return sum(len(m) for m in self.missing.values())

    def lost(self, sent: dict[str, int]) -> int:
        """Records of ``sent`` (robot -> how many it sent, numbered from 1) never received:
        :meth:`gaps` plus every robot's tail after its last received record."""
        return self.gaps() + sum(max(0, n - self.last.get(r, 0)) for r, n in sent.items())

    def in_order(self) -> bool:
        """Every robot's records arrived in sequence order, none twice."""
        return self.late == 0 and self.duplicate == 0


@dataclass(frozen=True)
class StatusBusResult:
    """One run; latencies in ms."""

    mode: str
    batch_delay_ms: float | None
    events: int
    robots: int
    workers: int
    hz: float
    seconds: float
    spread: float
    sent: int
    received: int
    lost: int
    lost_in_gaps: int
    late: int
    duplicate: int
    p50_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float
    malformed: int
    malformed_sent: int
    max_worker_lag_ms: float
    worker_cpu_us_per_record: float
    subscriber_cpu_s: float
    puts: int
    load_average: float

    @property
    def ok(self) -> bool:
        return (
            self.lost == 0
            and self.late == 0
            and self.duplicate == 0
            and self.received == self.sent
            and self.malformed == self.malformed_sent
        )


def percentile_ms(sorted_s: list[float], q: float) -> float:
    """The ``q`` quantile (nearest rank) of ascending latencies in s, in ms; NaN if empty."""
    if not sorted_s:
        return float("nan")
    return sorted_s[min(len(sorted_s) - 1, int(q * len(sorted_s)))] * 1e3


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class WorkerSpec:
    endpoint: str
    index: int
    workers: int
    first: int
    count: int
    hz: float
    seconds: float
    spread: float
    mode: str
    bad: int
    batch_delay_s: float | None


def _wait_matched(session: zenoh.Session, key: str) -> None:
    """Until the router has told this client of a subscriber for ``key`` (or CONNECT_S)."""
    pub = session.declare_publisher(key)
    try:
        end = time.monotonic() + CONNECT_S
        while not pub.matching_status.matching and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        pub.undeclare()


# long: the child's whole life (connect, handshake, paced rounds, counts), read top to bottom
def worker(spec: WorkerSpec) -> int:
    """Child process: connect, say ``ready`` on stdout, read the start time (wall s) from stdin,
    then publish robots ``robot<first>``.. every ``1/hz`` s for ``seconds``. Prints one JSON
    line of counts."""
    session = open_session(spec.endpoint, "client", connect_timeout_s=CONNECT_S)
    source = f"bench-w{spec.index}"
    bus = StatusBus(
        session, batch_source=source if spec.mode == "batch" else None, batch_delay_s=spec.batch_delay_s
    )
    names = [f"robot{spec.first + i}" for i in range(spec.count)]
    rounds = max(1, round(spec.seconds * spec.hz))
    period = 1.0 / spec.hz
    max_lag = 0.0
    try:
        _wait_matched(session, status_batch_key(source) if spec.mode == "batch" else status_key(names[0]))
        for i in range(spec.bad):
            session.put(
                status_batch_key(source),
                b"\xc1 not a batch" if i % 2 else b"{}",
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        for k in range(WARM_ROUNDS):  # a fresh link's first large messages take 10-40 ms
            for _ in range(min(spec.count, MAX_BATCH_RECORDS)):
                bus.publish_status(record(f"{WARM_ROBOT}{spec.index}", k + 1, time.time()))
            bus.flush_statuses()
        bus.status_puts = 0
        print("ready", flush=True)
        start = float(sys.stdin.readline()) + spec.index / spec.workers * period
        cpu0 = time.process_time()
        for k in range(rounds):
            due = start + k * period
            lag = time.time() - due
            if lag < 0:
                time.sleep(-lag)
            else:
                max_lag = max(max_lag, lag)
            step = spec.spread * period / spec.count
            for j, name in enumerate(names):
                if step > 0:  # agents ticking in turn: no further ahead of schedule than PACE_S
                    wait = due + j * step - time.time()
                    if wait > PACE_S:
                        time.sleep(wait)
                bus.publish_status(record(name, k + 1, time.time()))
            bus.flush_statuses()
        cpu = time.process_time() - cpu0
        out = {
            "rounds": rounds,
            "bad": spec.bad,
            "max_lag_ms": max_lag * 1e3,
            "cpu_s": cpu,
            "puts": bus.status_puts,
        }
        print(json.dumps(out), flush=True)
        # a session closed at once drops what its queues still hold: wait for the main process
        # to have counted (or given up), it says so on stdin (or ends, and stdin closes)
        sys.stdin.readline()
    finally:
        bus.close()
        session.close()
    return 0


def _spawn(spec: WorkerSpec) -> subprocess.Popen[str]:
    env = dict(os.environ)
    root = str(Path(fleet.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(asdict(spec))]
    return subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)


def _read_line(p: subprocess.Popen[str], timeout_s: float) -> str:
    """The worker's next stdout line, or RuntimeError after ``timeout_s`` or if it exited."""
    box: list[str] = []
    assert p.stdout is not None
    stdout = p.stdout
    t = threading.Thread(target=lambda: box.append(stdout.readline()), daemon=True)
    t.start()
    t.join(timeout_s)
    if not box or not box[0]:
        raise RuntimeError(f"worker {p.pid} said nothing within {timeout_s:g} s (exit {p.poll()})")
    return box[0].strip()


# long: one run start to end (router, subscriber, workers' handshake, drain, figures)
def run(
    robots: int,
    workers: int,
    hz: float,
    seconds: float,
    *,
    spread: float = 0.8,
    mode: str = "batch",
    malformed: int = 4,
    batch_delay_s: float | None = MAX_BATCH_DELAY_S,
    events: int = 0,
    tally: SeqTally | None = None,
) -> StatusBusResult:
    """One run: open the router and subscriber, start the workers, count every record (into
    ``tally`` if given, which the caller can then inspect robot by robot), close every session
    and wait for every child. ``events``: the subscriber's ``max_events`` (0, as the runner's
    bus; before this work the runner's kept 10,000 events nobody read)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(endpoint, "router")
    bus = StatusBus(session, max_events=events)
    tally = SeqTally() if tally is None else tally
    lock = threading.Lock()

    def on_status(rec: StatusRecord) -> None:
        now = time.time()
        if rec.robot.startswith(WARM_ROBOT):
            return
        with lock:
            tally.take(rec.robot, rec.seq, now - rec.t)

    procs: list[subprocess.Popen[str]] = []
    outs: list[dict[str, float]] = []
    sent_by_robot: dict[str, int] = {}
    cpu0 = time.process_time()
    try:
        bus.subscribe_statuses(on_status)
        first = 1
        specs = []
        for i in range(workers):
            n = robots // workers + (1 if i < robots % workers else 0)
            bad = malformed if i == 0 and mode == "batch" else 0
            spec = WorkerSpec(endpoint, i, workers, first, n, hz, seconds, spread, mode, bad, batch_delay_s)
            specs.append(spec)
            procs.append(_spawn(specs[-1]))
            first += n
        for p in procs:
            if _read_line(p, CONNECT_S + 30.0) != "ready":
                raise RuntimeError(f"worker {p.pid} did not get ready")
        start = f"{time.time() + 0.5}\n"
        for p in procs:
            assert p.stdin is not None
            p.stdin.write(start)
            p.stdin.flush()
        for spec, p in zip(specs, procs, strict=True):
            out = json.loads(_read_line(p, seconds * 3 + 120.0))
            outs.append(out)
            for r in range(spec.first, spec.first + spec.count):
                sent_by_robot[f"robot{r}"] = int(out["rounds"])
        sent = sum(sent_by_robot.values())
        end = time.monotonic() + DRAIN_S
        while time.monotonic() < end:  # until every record is in, or the drain time is up
            with lock:
                if tally.received >= sent:
                    break
            time.sleep(0.01)
        time.sleep(0.1)  # a late duplicate would show
        for p in procs:  # counted: the workers may close their sessions
            assert p.stdin is not None
            p.stdin.write("close\n")
            p.stdin.flush()
        for p in procs:
            p.wait(timeout=60.0)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        bus.close()
        session.close()
    with lock:
        vals = sorted(tally.latencies)
        lost = tally.lost(sent_by_robot)
        gaps = tally.gaps()
    return StatusBusResult(
        mode=mode,
        batch_delay_ms=None if batch_delay_s is None else batch_delay_s * 1e3,
        events=events,
        robots=robots,
        workers=workers,
        hz=hz,
        seconds=seconds,
        spread=spread,
        sent=sent,
        received=tally.received,
        lost=lost,
        lost_in_gaps=gaps,
        late=tally.late,
        duplicate=tally.duplicate,
        p50_ms=percentile_ms(vals, 0.50),
        p95_ms=percentile_ms(vals, 0.95),
        p99_ms=percentile_ms(vals, 0.99),
        max_ms=percentile_ms(vals, 1.0),
        malformed=bus.malformed,
        malformed_sent=int(sum(o["bad"] for o in outs)),
        max_worker_lag_ms=max(o["max_lag_ms"] for o in outs),
        worker_cpu_us_per_record=sum(o["cpu_s"] for o in outs) / sent * 1e6 if sent else float("nan"),
        subscriber_cpu_s=time.process_time() - cpu0,
        puts=int(sum(o["puts"] for o in outs)),
        load_average=os.getloadavg()[0],
    )


def cpu_per_record(events: int, batches: int = 100, repeats: int = 9) -> float:
    """CPU µs per record for the subscriber's share: decode a 500-record batch, take it into a
    ``StatusBus`` keeping ``events`` events, call one coordinator-like callback (lock +
    append); the best of ``repeats`` rounds of ``batches`` batches (process CPU time)."""
    data = encode_batch("w0", [record(f"robot{i}", 5, 1.0) for i in range(MAX_BATCH_RECORDS)])
    lock, inbox = threading.Lock(), []

    def cb(rec: StatusRecord) -> None:
        with lock:
            inbox.append(rec)

    with zenoh.open(zenoh.Config.from_json5('{mode: "peer", scouting: {multicast: {enabled: false}}}')) as s:
        bus = StatusBus(s, max_events=events)
        bus.subscribe_statuses(cb)
        take = bus._take  # noqa: SLF001 - what the Zenoh callback runs after taking the payload
        best = float("inf")
        for _ in range(repeats):
            t0 = time.process_time()
            for _ in range(batches):
                take("k", decode_batch(data).records)
            best = min(best, time.process_time() - t0)
            inbox.clear()
        bus.close()
    return best / (batches * MAX_BATCH_RECORDS) * 1e6


def _ints(text: str) -> list[int]:
    vals = [int(v) for v in text.split(",") if v.strip()]
    if not vals or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers like 1000,5000, got {text!r}")
    return vals


def _delays(text: str) -> list[float | None]:
    """``5,none`` -> [0.005, None] (s)."""
    out: list[float | None] = []
    for v in text.split(","):
        v = v.strip().lower()
        if v in ("none", "off"):
            out.append(None)
        elif v:
            ms = float(v)
            if not ms >= 0:
                raise argparse.ArgumentTypeError(f"a batch delay is >= 0 ms or none, got {v!r}")
            out.append(ms / 1e3)
    if not out:
        raise argparse.ArgumentTypeError("expected delays in ms like 5,none")
    return out


def _row(r: StatusBusResult) -> str:
    delay = "none" if r.batch_delay_ms is None else f"{r.batch_delay_ms:g}"
    return (
        f"{r.robots:6d} {r.workers:7d} {delay:>5s} {r.events:6d} {r.sent:9d} {r.received:9d} {r.lost:5d} {r.late:4d} "
        f"{r.duplicate:3d} {r.p50_ms:7.2f} {r.p95_ms:7.2f} {r.p99_ms:7.2f} {r.max_ms:7.2f} "
        f"{r.malformed:4d}/{r.malformed_sent:<4d} {r.puts:6d}   (workers <= {r.max_worker_lag_ms:.1f} ms "
        f"late, {r.worker_cpu_us_per_record:.1f} µs CPU/record; subscriber CPU {r.subscriber_cpu_s:.1f} s; "
        f"load {r.load_average:.1f})"
        + (f" lost in gaps {r.lost_in_gaps}" if r.lost else "")
        + ("" if r.ok else "  << LOSS, DISORDER OR MISCOUNT")
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument(
        "--robots", type=_ints, default=[1000, 5000, 10000], help="sizes (default 1000,5000,10000)"
    )
    ap.add_argument(
        "--workers", type=_ints, default=[4], help="publishing processes per run (default 4; e.g. 1,2,4)"
    )
    ap.add_argument(
        "--hz",
        type=float,
        default=10.0,
        help="records per robot per second (default 10: the shipped configs publish every agent tick; "
        "a load test's default is 1)",
    )
    ap.add_argument(
        "--seconds", type=float, default=10.0, help="publishing time per run, wall s (default 10)"
    )
    ap.add_argument(
        "--spread",
        type=float,
        default=0.8,
        help="fraction of each period over which a worker builds its records, one robot after another "
        "(default 0.8; 0: all at once)",
    )
    ap.add_argument("--mode", choices=("batch", "single"), default="batch")
    ap.add_argument(
        "--batch-delay-ms",
        type=_delays,
        default=[MAX_BATCH_DELAY_S],
        help=f"the workers' StatusBus batch_delay_s, in ms; a list runs each (default {(MAX_BATCH_DELAY_S or 0) * 1e3:g}; "
        "none: a batch leaves only when full or at the round's end, as before)",
    )
    ap.add_argument(
        "--events",
        type=lambda v: [int(x) for x in v.split(",")],
        default=[0],
        help="the subscriber StatusBus's max_events; a list runs each (default 0, as the runner's; "
        "10000: the runner's before this work)",
    )
    ap.add_argument(
        "--compare",
        action="store_true",
        help="each size and worker count twice, one right after the other: as before this work "
        "(batch delay none, subscriber events 10000), then as now (the defaults); overrides "
        "--batch-delay-ms and --events",
    )
    ap.add_argument("--malformed", type=int, default=4, help="bad batches injected by worker 0 (default 4)")
    ap.add_argument("--json", action="store_true", help="also print each result as a JSON line")
    ap.add_argument(
        "--cpu-per-record",
        action="store_true",
        help="only the subscriber's CPU per record (decode, intake, a callback), with the event "
        "queue off and on; no processes, no router",
    )
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        return worker(WorkerSpec(**json.loads(a.worker)))
    if a.cpu_per_record:
        for events in (0, 10000):
            print(
                f"subscriber CPU per record, max_events={events}: {cpu_per_record(events):.2f} µs", flush=True
            )
        return 0
    if a.hz <= 0 or a.seconds <= 0 or not 0 <= a.spread < 1 or a.malformed < 0:
        ap.error("--hz and --seconds must be positive, --spread in [0, 1), --malformed >= 0")
    ok = True
    print(
        f"status_bus: {a.mode}, {a.hz:g} Hz per robot, {a.seconds:g} s per run, records built over "
        f"{a.spread:.0%} of each period; router + StatusBus subscriber in this process"
    )
    print(
        "robots workers delay events      sent  received  lost late dup  p50 ms  p95 ms  p99 ms  max ms malformed  puts"
    )
    for robots in a.robots:
        for workers in a.workers:
            pairs = (
                [(None, 10000), (MAX_BATCH_DELAY_S, 0)]
                if a.compare
                else list(itertools.product(a.batch_delay_ms, a.events))
            )
            for delay, events in pairs:
                r = run(
                    robots,
                    workers,
                    a.hz,
                    a.seconds,
                    spread=a.spread,
                    mode=a.mode,
                    malformed=a.malformed,
                    batch_delay_s=delay,
                    events=events,
                )
                print(_row(r), flush=True)
                if a.json:
                    print(json.dumps(asdict(r)), flush=True)
                ok = ok and r.ok
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
