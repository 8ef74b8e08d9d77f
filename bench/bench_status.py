"""Status of 10,000 robots on the bus: delivered fraction and latency through a Zenoh router.

Topology (loopback, scouting off, ``tcp/127.0.0.1:<free port>``): this process opens the
**router** session and the coordinator's kind of subscriber, a
:class:`~fleet.bus.status_bus.StatusBus` with ``subscribe_statuses(callback)`` (every record
decoded and validated as the coordinator's are); ``--workers`` child processes (clients, as
``fleet loadtest --workers K`` runs its agents) each own a share of the ``--robots`` robots and
publish all their robots' records once per ``1 / --hz`` s:

* ``--mode batch`` (what a process with many agents does, ``bus.status_batch``): the round's
  records go out as batches of :data:`~fleet.messages.status_batch.MAX_BATCH_RECORDS` on
  ``fleet/batch/<worker>/status`` (``StatusBus.publish_status`` then ``flush_statuses``);
* ``--mode single``: one put per record on ``fleet/<robot>/status``;
* ``--mode both`` runs the two one after the other (ratios in one run).

The workers' rounds are spread over the period (worker ``i`` starts ``i / workers`` of a
period later), as independent processes' ticks are; with ``--spread`` each worker also sends its
batches spread over its period, as a worker ticking its agents one after another does (without
it, all of a worker's records are built and sent at once: the worst case for latency, since
the subscriber decodes the whole burst in turn). Each record is stamped (its ``t``) with
the wall time at which it was *built*, so the latency includes the wait for the rest of its
batch, the put, the router and the subscriber's decoding: receive time minus ``t`` (one
machine, one clock). The first worker also sends ``--malformed`` bad batches, which the
subscriber must count. Prints, per mode: delivered / sent, p50 / p99 / max latency, the
workers' lag behind schedule and CPU per record, the subscriber's CPU. Exit 1 if any record
was lost or malformed messages were not counted.

    python bench/bench_status.py                                   # 10,000 robots at 1 Hz, both modes
    python bench/bench_status.py --robots 10000 --hz 10 --mode batch --spread
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import zenoh
from bench_zenoh import _percentile, free_port, record

import fleet
from fleet.bus.keys import status_batch_key
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord
from fleet.messages.status_batch import MAX_BATCH_RECORDS

#: Wall seconds the workers get to connect before publishing starts.
WARMUP_S = 3.0
#: Wall seconds the subscriber waits for stragglers after the workers finished.
DRAIN_S = 1.0


@dataclass(frozen=True)
class StatusBenchResult:
    """One mode's run; latencies in ms."""

    mode: str
    robots: int
    hz: float
    seconds: float
    workers: int
    sent: int
    delivered: int
    delivered_fraction: float
    p50_ms: float
    p99_ms: float
    max_ms: float
    malformed: int
    malformed_sent: int
    max_worker_lag_ms: float
    worker_cpu_us_per_record: float
    subscriber_cpu_s: float
    puts: int


def worker(
    endpoint: str,
    index: int,
    first: int,
    count: int,
    hz: float,
    seconds: float,
    start: float,
    mode: str,
    bad: int,
    spread: bool = False,
) -> int:
    """Child process: publish robots ``robot<first>``.. every ``1/hz`` s from ``start`` (shifted
    by this worker's share of the period). Prints one JSON line of counts."""
    session = open_session(endpoint, "client", connect_timeout_s=10.0)
    source = f"bench-w{index}"
    bus = StatusBus(session, batch_source=source if mode == "batch" else None)
    names = [f"robot{first + i}" for i in range(count)]
    chunk = MAX_BATCH_RECORDS
    sent, max_lag, cpu = 0, 0.0, 0.0
    try:
        for i in range(bad):
            session.put(
                status_batch_key(source),
                b"\xc1 not a batch" if i % 2 else b"{}",
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        rounds = max(1, round(seconds * hz))
        shift = start + (index / max(1, int(os.environ.get("BENCH_WORKERS", "1")))) / hz
        while time.time() < shift:
            time.sleep(min(0.01, max(0.0, shift - time.time())))
        cpu0 = time.process_time()
        for k in range(rounds):
            due = shift + k / hz
            lag = time.time() - due
            if lag < 0:
                time.sleep(-lag)
            else:
                max_lag = max(max_lag, lag)
            for j in range(0, count, chunk):
                if spread and j:  # as agents ticking one after another would: over the period
                    wait = due + (j / count) / hz - time.time()
                    if wait > 0:
                        time.sleep(wait)
                for n in names[j : j + chunk]:
                    bus.publish_status(record(n, k + 1, time.time()))
                bus.flush_statuses()
            sent += count
        cpu = time.process_time() - cpu0
        puts = bus.status_puts
    finally:
        bus.close()
        session.close()
    print(
        json.dumps({"sent": sent, "bad": bad, "max_lag_ms": max_lag * 1e3, "cpu_s": cpu, "puts": puts}),
        flush=True,
    )
    return 0


def _pct(vals: list[float], q: float) -> float:
    """The ``q`` percentile of the sorted latencies ``vals`` (s), in ms."""
    return _percentile(vals, q) * 1e3


def run(
    mode: str, robots: int, hz: float, seconds: float, workers: int, malformed: int, spread: bool = False
) -> StatusBenchResult:
    """One mode: start the workers, collect every record, stop and clean up."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(endpoint, "router")
    bus = StatusBus(session, max_events=0)
    lat: list[float] = []
    lock = threading.Lock()

    def on_status(rec: StatusRecord) -> None:
        d = time.time() - rec.t
        with lock:
            lat.append(d)

    procs: list[subprocess.Popen[str]] = []
    outs: list[dict[str, float]] = []
    cpu0 = time.process_time()
    try:
        bus.subscribe_statuses(on_status)
        start = time.time() + WARMUP_S
        env = dict(os.environ, BENCH_WORKERS=str(workers))
        root = str(Path(fleet.__file__).resolve().parent.parent)
        env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
        first = 1
        for i in range(workers):
            n = robots // workers + (1 if i < robots % workers else 0)
            spec = f"{endpoint},{i},{first},{n},{hz},{seconds},{start},{mode},{malformed if i == 0 else 0},{int(spread)}"
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", spec]
            procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env))
            first += n
        for p in procs:
            out, _ = p.communicate(timeout=WARMUP_S + seconds + 120.0)
            if p.returncode != 0:
                raise RuntimeError(f"worker {p.pid} exited with {p.returncode}")
            outs.append(json.loads(out.strip().splitlines()[-1]))
        sent = int(sum(o["sent"] for o in outs))
        end = time.monotonic() + DRAIN_S * 10
        while time.monotonic() < end:  # until every record is in, or the drain time is up
            with lock:
                if len(lat) >= sent:
                    break
            time.sleep(0.01)
        time.sleep(DRAIN_S if mode == "single" else 0.1)  # late copies would show as extra
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        bus.close()
        session.close()
    with lock:
        vals = sorted(lat)
    return StatusBenchResult(
        mode=mode,
        robots=robots,
        hz=hz,
        seconds=seconds,
        workers=workers,
        sent=sent,
        delivered=len(vals),
        delivered_fraction=len(vals) / sent if sent else float("nan"),
        p50_ms=_pct(vals, 0.50),
        p99_ms=_pct(vals, 0.99),
        max_ms=_pct(vals, 1.0),
        malformed=bus.malformed,
        malformed_sent=int(sum(o["bad"] for o in outs)),
        max_worker_lag_ms=max(o["max_lag_ms"] for o in outs),
        worker_cpu_us_per_record=sum(o["cpu_s"] for o in outs) / sent * 1e6 if sent else float("nan"),
        subscriber_cpu_s=time.process_time() - cpu0,
        puts=int(sum(o["puts"] for o in outs)),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=10000, help="robots (default 10000)")
    ap.add_argument(
        "--hz", type=float, default=1.0, help="records per robot per second (default 1, the load-test rate)"
    )
    ap.add_argument("--seconds", type=float, default=10.0, help="publishing time, wall s (default 10)")
    ap.add_argument("--workers", type=int, default=4, help="publishing processes (default 4)")
    ap.add_argument("--mode", choices=("batch", "single", "both"), default="both")
    ap.add_argument(
        "--spread",
        action="store_true",
        help="each worker sends its batches spread over the period, as agents ticking one after "
        "another do (default: all of a worker's records at once, the worst case)",
    )
    ap.add_argument("--malformed", type=int, default=4, help="bad batches injected by worker 0 (default 4)")
    ap.add_argument("--json", action="store_true", help="also print each result as a JSON line")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        ep, i, first, n, hz, secs, start, mode, bad, spread = a.worker.split(",")
        return worker(
            ep,
            int(i),
            int(first),
            int(n),
            float(hz),
            float(secs),
            float(start),
            mode,
            int(bad),
            spread == "1",
        )
    if a.robots < 1 or a.hz <= 0 or a.seconds <= 0 or a.workers < 1 or a.malformed < 0:
        ap.error("--robots, --hz, --seconds, --workers must be positive, --malformed >= 0")
    print(
        f"bench_status: publishing {'spread over each period' if a.spread else 'in one burst per period and worker'}"
    )
    ok = True
    for mode in ("batch", "single") if a.mode == "both" else (a.mode,):
        r = run(mode, a.robots, a.hz, a.seconds, a.workers, a.malformed if mode == "batch" else 0, a.spread)
        print(
            f"bench_status [{mode}]: {r.robots} robots x {r.hz:g} Hz for {r.seconds:g} s from {r.workers} worker "
            f"processes -> router + StatusBus subscriber ({r.puts} puts)\n"
            f"  delivered {r.delivered}/{r.sent} ({100 * r.delivered_fraction:.3f}%)\n"
            f"  latency p50 {r.p50_ms:.2f} ms, p99 {r.p99_ms:.2f} ms, max {r.max_ms:.2f} ms\n"
            f"  malformed counted {r.malformed} (injected {r.malformed_sent}); workers at most "
            f"{r.max_worker_lag_ms:.1f} ms behind schedule, {r.worker_cpu_us_per_record:.1f} µs CPU per record; "
            f"subscriber CPU {r.subscriber_cpu_s:.1f} s",
            flush=True,
        )
        if a.json:
            print(json.dumps(asdict(r)))
        ok = ok and r.delivered == r.sent and r.malformed == r.malformed_sent
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
