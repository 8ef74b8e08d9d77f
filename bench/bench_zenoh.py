"""Zenoh status-bus throughput and latency: N robots publishing status records at H Hz.

Topology (all on loopback, scouting off, endpoint ``tcp/127.0.0.1:<free port>``):

* this process opens the **router** session (``fleet.bus.session.open_session(endpoint,
  "router")``) and the coordinator-style subscriber: a :class:`~fleet.bus.status_bus.StatusBus`
  with ``subscribe_statuses(callback)`` on ``fleet/*/status`` (every payload is parsed and
  validated as a :class:`~fleet.messages.StatusRecord`, as the coordinator's is);
* ``--publishers`` child processes (default 2) connect in **client** mode and each publishes
  the status of its share of the ``--robots`` robots every ``1/hz`` s with
  ``StatusBus.publish_status`` (the same JSON the agents send). The record's ``t`` field
  carries the send time (``time.time()``; both ends are on one machine), so the subscriber
  measures latency as receive time minus ``t``. The first publisher also sends (before
  publishing) ``--malformed`` bad payloads on status keys, which the subscriber must count and drop.

Prints delivered/sent, messages/s received, p50 / p99 / max latency, the malformed count
(expected: exactly ``--malformed``), how far behind schedule the publishers fell, the CPU
seconds the subscriber process used and the publishers' CPU per record sent (building,
encoding and putting it). ``--hz 0`` publishes as fast as the publishers can for
``--seconds`` (throughput: statuses are sent with congestion control *drop*, so under
overload some are lost and the delivered fraction is reported, not checked). Every session
is closed and every child process is waited for (killed after a timeout), so nothing is left
behind. The children import the same ``fleet`` package as this process, so pointing
``PYTHONPATH`` at another checkout measures that checkout's bus with this script.

    python bench/bench_zenoh.py --robots 1000 --hz 10 --seconds 10
    python bench/bench_zenoh.py --robots 200 --hz 10 --seconds 3 --publishers 1
    python bench/bench_zenoh.py --robots 1000 --hz 0 --seconds 5 --publishers 1
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import zenoh

import fleet
from fleet.bus.keys import status_key
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

#: Wall seconds the children get to connect before publishing starts.
WARMUP_S = 2.0
#: Wall seconds the subscriber waits for stragglers after the publishers finished.
DRAIN_S = 1.0


@dataclass(frozen=True)
class ZenohBenchResult:
    """One run. Latencies in ms; ``msgs_per_s`` = delivered / publishing wall time."""

    robots: int
    hz: float
    seconds: float
    publishers: int
    sent: int
    delivered: int
    delivered_fraction: float
    msgs_per_s: float
    p50_ms: float
    p99_ms: float
    max_ms: float
    malformed: int
    malformed_sent: int
    max_publisher_lag_ms: float
    subscriber_cpu_s: float
    publisher_cpu_us_per_msg: float
    payload_bytes: int


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def record(robot: str, seq: int, t: float) -> StatusRecord:
    """A typical patrol status record for ``robot`` stamped with send time ``t``."""
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


def publisher(
    endpoint: str, first: int, count: int, hz: float, seconds: float, start: float, bad: int
) -> int:
    """Child process: publish robots ``robot<first>`` .. for ``seconds`` from wall time ``start``
    (``hz`` 0: back to back). Prints one JSON line ``{"sent", "malformed_sent", "max_lag_ms",
    "cpu_s"}`` (``cpu_s``: this process's CPU while publishing)."""
    session = open_session(endpoint, "client", connect_timeout_s=5.0)
    bus = StatusBus(session)
    names = [f"robot{first + i}" for i in range(count)]
    sent = 0
    max_lag = 0.0
    cpu = 0.0
    try:
        for n in names:  # declare the publishers up front, outside the paced loop
            bus._publisher(status_key(n), False)
        for i in range(bad):  # early and reliably: puts still queued at close() can be lost
            payload = b"{not json" if i % 2 == 0 else b'{"v":1,"robot":"robot1"}'
            session.put(status_key(names[0]), payload, congestion_control=zenoh.CongestionControl.BLOCK)
        while time.time() < start:
            time.sleep(min(0.01, max(0.0, start - time.time())))
        cpu0 = time.process_time()
        rounds = round(seconds * hz) if hz > 0 else sys.maxsize
        end = start + seconds
        for k in range(rounds):
            if hz > 0:
                due = start + k / hz
                lag = time.time() - due
                if lag < 0:
                    time.sleep(-lag)
                else:
                    max_lag = max(max_lag, lag)
            elif time.time() >= end:
                break
            for n in names:
                bus.publish_status(record(n, k, time.time()))
                sent += 1
        cpu = time.process_time() - cpu0
    finally:
        bus.close()
        session.close()
    out = {"sent": sent, "malformed_sent": bad, "max_lag_ms": max_lag * 1e3, "cpu_s": cpu}
    print(json.dumps(out), flush=True)
    return 0


def _percentile(sorted_vals: list[float], q: float) -> float:
    if not sorted_vals:
        return float("nan")
    return sorted_vals[min(len(sorted_vals) - 1, int(q * len(sorted_vals)))]


def run(robots: int, hz: float, seconds: float, publishers: int, malformed: int) -> ZenohBenchResult:
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
        share = [robots // publishers + (1 if i < robots % publishers else 0) for i in range(publishers)]
        first = 1
        env = dict(os.environ)
        root = str(Path(fleet.__file__).resolve().parent.parent)  # the children use this fleet
        env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
        for i, n in enumerate(share):
            if n == 0:
                continue
            cmd = [
                sys.executable,
                str(Path(__file__).resolve()),
                "--publisher",
                f"{endpoint},{first},{n},{hz},{seconds},{start},{malformed if i == 0 else 0}",
            ]
            procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env))
            first += n
        for p in procs:
            try:
                out, _ = p.communicate(timeout=WARMUP_S + seconds + 30.0)
            except subprocess.TimeoutExpired:
                p.kill()
                out, _ = p.communicate()
            if p.returncode != 0:
                raise RuntimeError(f"publisher process {p.pid} exited with {p.returncode}")
            outs.append(json.loads(out.strip().splitlines()[-1]))
        time.sleep(DRAIN_S)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        bus.close()
        session.close()
    cpu = time.process_time() - cpu0
    with lock:
        vals = sorted(lat)
    sent = int(sum(o["sent"] for o in outs))
    delivered = len(vals)
    return ZenohBenchResult(
        robots=robots,
        hz=hz,
        seconds=seconds,
        publishers=len(procs),
        sent=sent,
        delivered=delivered,
        delivered_fraction=delivered / sent if sent else float("nan"),
        msgs_per_s=delivered / seconds,
        p50_ms=_percentile(vals, 0.50) * 1e3,
        p99_ms=_percentile(vals, 0.99) * 1e3,
        max_ms=(vals[-1] if vals else float("nan")) * 1e3,
        malformed=bus.malformed,
        malformed_sent=int(sum(o["malformed_sent"] for o in outs)),
        max_publisher_lag_ms=max((o["max_lag_ms"] for o in outs), default=0.0),
        subscriber_cpu_s=cpu,
        publisher_cpu_us_per_msg=sum(o["cpu_s"] for o in outs) / sent * 1e6 if sent else float("nan"),
        payload_bytes=len(record("robot1000", 17, time.time()).to_json()),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Throughput and latency of fleet/*/status over a Zenoh router on loopback: "
        "publisher processes (clients) -> this process (router + coordinator-style subscriber).",
    )
    ap.add_argument("--robots", type=int, default=1000, help="robots publishing status (default 1000)")
    ap.add_argument(
        "--hz",
        type=float,
        default=10.0,
        help="status records per robot per second (default 10; 0: as fast as possible)",
    )
    ap.add_argument("--seconds", type=float, default=10.0, help="publishing time, wall seconds (default 10)")
    ap.add_argument("--publishers", type=int, default=2, help="publisher processes (default 2)")
    ap.add_argument("--malformed", type=int, default=10, help="bad payloads to inject (default 10)")
    ap.add_argument("--json", action="store_true", help="also print the result as one JSON line")
    ap.add_argument("--publisher", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.publisher:
        ep, first, count, hz, secs, start, bad = a.publisher.split(",")
        return publisher(ep, int(first), int(count), float(hz), float(secs), float(start), int(bad))
    if a.robots < 1 or a.hz < 0 or a.seconds <= 0 or a.publishers < 1 or a.malformed < 0:
        ap.error("--robots, --seconds, --publishers must be positive, --hz and --malformed >= 0")
    r = run(a.robots, a.hz, a.seconds, a.publishers, a.malformed)
    rate = f"{r.hz:g} Hz" if r.hz > 0 else "as fast as possible"
    print(
        f"bench_zenoh: {r.robots} robots x {rate} for {r.seconds:g} s, {r.publishers} publisher "
        f"process(es) -> router + StatusBus subscriber ({r.payload_bytes}-byte JSON records)\n"
        f"  delivered {r.delivered}/{r.sent} ({100 * r.delivered_fraction:.2f}%), {r.msgs_per_s:,.0f} msgs/s\n"
        f"  latency p50 {r.p50_ms:.2f} ms, p99 {r.p99_ms:.2f} ms, max {r.max_ms:.2f} ms\n"
        f"  malformed counted {r.malformed} (injected {r.malformed_sent}); publishers at most "
        f"{r.max_publisher_lag_ms:.1f} ms behind schedule\n"
        f"  subscriber process CPU {r.subscriber_cpu_s:.1f} s "
        f"({r.subscriber_cpu_s / (r.seconds + WARMUP_S + DRAIN_S):.2f} of one core over the run); "
        f"publishers {r.publisher_cpu_us_per_msg:.1f} µs CPU per record sent"
    )
    if a.json:
        print(json.dumps(asdict(r)))
    ok = (r.hz == 0 or r.delivered_fraction >= 0.99) and r.malformed == r.malformed_sent
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
