"""What the secured bus costs: status records through an open router against a secured one.

In one process, on loopback (scouting off, a free ``tcp/127.0.0.1`` port), for each mode:

* a router session: ``open`` (no credentials, no rules) or ``secured`` (``fleet keys init`` for
  a fleet of ``--fleet`` robots: passwords and the access control generated for all of them,
  ``--tls`` also mutual TLS);
* ``--robots`` client sessions, each with its own identity when secured, each publishing its
  robot's status with ``StatusBus.publish_status`` (a declared publisher, congestion *block*
  off: *drop*, as agents do) as fast as it can for ``--messages`` records;
* one coordinator-style subscriber (``fleet/*/status``, every record parsed and validated).

Prints, per mode, the records delivered of those sent, records per second delivered, the
time ``fleet keys init`` took for ``--fleet`` robots and the size of the router config, and the
secured / open throughput ratio of this one run (absolute rates on the shared 2-core machine are
noisy; compare the ratio). Every session is closed.

    python bench/bench_secure_bus.py --robots 20 --messages 2000 --fleet 1000
    python bench/bench_secure_bus.py --robots 20 --messages 2000 --fleet 1000 --tls
"""

from __future__ import annotations

import argparse
import json
import socket
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from fleet.bus.keyring import init_keyring
from fleet.bus.session import Secure, open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

#: Wall seconds to wait for stragglers after the publishers finished.
DRAIN_S = 2.0


def status_record(robot: str, seq: int) -> StatusRecord:
    """A typical patrol status record of ``robot``."""
    return StatusRecord(
        robot=robot, ns=f"/{robot}", t=0.1 * seq, pose=(12.25, 7.5, 1.5708), battery=0.83, charging=False,
        stuck=False, bt="RUNNING", leaf="FollowRoute", mode="patrol", task_id="p-0003", laps=2, progress=0.4,
        distance_m=123.4, collisions=0, seq=seq,
    )  # fmt: skip


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def run_mode(secure_dir: Path | None, robots: int, messages: int) -> dict[str, float]:
    """One mode: delivered / sent and delivered records per second."""
    ep = _endpoint()
    if secure_dir is not None:
        init_keyring(secure_dir, [f"robot{i}" for i in range(1, FLEET + 1)], ep, force=True, tls=TLS)
    t_open = time.perf_counter()
    router = open_session(ep, "router", secure=Secure(secure_dir, "router") if secure_dir else None)
    router_open_s = time.perf_counter() - t_open
    sessions: list[zenoh.Session] = []
    got = 0
    lock = threading.Lock()

    def seen(_rec: object) -> None:
        nonlocal got
        with lock:
            got += 1

    try:
        coord = open_session(
            ep,
            "client",
            secure=Secure(secure_dir, "coordinator") if secure_dir else None,
            connect_timeout_s=30,
        )
        sessions.append(coord)
        sub = StatusBus(coord)
        sub.subscribe_statuses(seen)
        buses = []
        for i in range(1, robots + 1):
            name = f"robot{i}"
            s = open_session(
                ep, "client", secure=Secure(secure_dir, name) if secure_dir else None, connect_timeout_s=30
            )
            sessions.append(s)
            buses.append((name, StatusBus(s)))
        time.sleep(1.0)  # declarations reach the router (measurement start, not a correctness wait)
        with lock:
            got = 0

        def publish(name: str, bus: StatusBus) -> None:
            for k in range(messages):
                bus.publish_status(status_record(name, k))

        threads = [threading.Thread(target=publish, args=nb) for nb in buses]
        t0 = time.perf_counter()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        sent = robots * messages
        deadline = time.perf_counter() + DRAIN_S
        while time.perf_counter() < deadline and got < sent:
            time.sleep(0.01)
        wall = time.perf_counter() - t0
        for _, b in buses:
            b.close()
        sub.close()
        return {
            "delivered": got / sent,
            "msgs_per_s": got / wall,
            "malformed": sub.malformed,
            "router_open_s": router_open_s,
        }
    finally:
        for s in sessions:
            s.close()  # type: ignore[no-untyped-call]
        router.close()  # type: ignore[no-untyped-call]


FLEET = 1000
TLS = False


def main() -> None:
    global FLEET, TLS
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=20, help="publishing robot sessions (20)")
    p.add_argument("--messages", type=int, default=2000, help="records per robot (2000)")
    p.add_argument("--fleet", type=int, default=1000, help="robots in the generated keys and rules (1000)")
    p.add_argument("--tls", action="store_true", help="secured mode also over mutual TLS")
    p.add_argument("--json", action="store_true", help="one JSON line")
    args = p.parse_args()
    FLEET, TLS = max(args.fleet, args.robots), args.tls
    with tempfile.TemporaryDirectory() as tmp:
        keys = Path(tmp) / "keys"
        t0 = time.perf_counter()
        init_keyring(keys, [f"robot{i}" for i in range(1, FLEET + 1)], _endpoint(), tls=TLS)
        init_s = time.perf_counter() - t0
        router_kb = (keys / "router.json5").stat().st_size / 1024
        open_r = run_mode(None, args.robots, args.messages)
        secured_r = run_mode(keys, args.robots, args.messages)
    out = {
        "robots": args.robots,
        "messages": args.messages,
        "fleet": FLEET,
        "tls": TLS,
        "keys_init_s": round(init_s, 2),
        "router_config_kb": round(router_kb, 1),
        "open": open_r,
        "secured": secured_r,
        "ratio": round(secured_r["msgs_per_s"] / open_r["msgs_per_s"], 3),
    }
    if args.json:
        print(json.dumps(out))
        return
    print(
        f"fleet keys init for {FLEET} robots{' with TLS' if TLS else ''}: {init_s:.2f} s, "
        f"router config {router_kb:.0f} kB"
    )
    for mode, r in (("open", open_r), ("secured", secured_r)):
        print(
            f"{mode:>8}: {args.robots} robots x {args.messages} records: delivered {r['delivered']:.1%}, "
            f"{r['msgs_per_s']:.0f} records/s, malformed {r['malformed']:.0f}, "
            f"router session opened in {r['router_open_s']:.2f} s"
        )
    print(f"secured / open throughput: {out['ratio']:.2f}")


if __name__ == "__main__":
    main()
