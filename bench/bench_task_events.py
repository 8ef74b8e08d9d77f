"""What the task service's events and the coordinator's first orders cost on a session that
holds a large fleet's in-process agents (issue 12, 10,000 robots: 60 % of the load test's loop
after set-up went to task-event puts, 12 % to declaring a task publisher per robot).

One router session on ``tcp/127.0.0.1:<free port>`` (scouting off) holds, per robot, what an
in-process agent declares: subscriptions to ``fleet/<robot>/task`` and ``fleet/<robot>/grant``
and the liveliness token ``fleet/<robot>/alive`` (:class:`~fleet.bus.status_bus.StatusBus`),
plus the runner's early-order guard. On it, a real :class:`~fleet.service.service.TaskService`
(``configs/warehouse_patrol.yaml``) with its Zenoh face (:class:`~fleet.service.bus_face.ServiceBus`).
Per robot count, in one run:

* **events, before**: one undeclared ``session.put`` per task event on
  ``fleet/service/events/<task id>`` (the face's behaviour before the matching gate);
* **events, no subscriber**: the face's listener now (nothing matches: counted, not sent);
* **events, watched**: the face with a subscriber on another session (client, through the
  router), which must receive every event;
* **orders, first use**: one ``publish_task`` per robot on a bus that declares each robot's
  publisher at its first order (as the coordinator's first assignment did);
* **orders, declared in set-up**: :meth:`StatusBus.declare_task_publishers` first (timed
  apart), then the same orders.

Prints ms per event / per order and the before/after ratios. Every session is closed.

    python bench/bench_task_events.py --robots 1000 2000 --events 2000
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from fleet.bus.keys import SERVICE_PREFIX
from fleet.bus.session import close_session, free_endpoint, open_session
from fleet.bus.status_bus import StatusBus
from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.messages import TaskMessage
from fleet.service.bus_face import ServiceBus
from fleet.service.records import TaskEvent
from fleet.service.service import TaskService

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "warehouse_patrol.yaml"


def _events(n: int, start: int) -> list[TaskEvent]:
    """``n`` assignment events of distinct tasks (ids from ``start``), as the first cycle makes."""
    return [
        TaskEvent(start + i, f"t-{start + i}", "assigned", "assigned", f"r{i}", f"a-{i}", "bench", 0.0, 0.0)
        for i in range(n)
    ]


def _old_put(session: zenoh.Session, service: TaskService) -> Callable[[TaskEvent], None]:
    """The face's listener before the matching gate: one undeclared put per event."""

    def on_event(ev: TaskEvent) -> None:
        rec = service.records.get(ev.task_id)
        msg = {"event": ev.to_dict(), "task": rec.to_dict() if rec is not None else None}
        session.put(f"{SERVICE_PREFIX}/events/{ev.task_id}", json.dumps(msg))

    return on_event


def _per_ms(fn: Callable[[TaskEvent], None], evs: list[TaskEvent]) -> float:
    t0 = time.perf_counter()
    for ev in evs:
        fn(ev)
    return (time.perf_counter() - t0) / len(evs) * 1e3


def _wait(cond: Callable[[], bool], what: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {what}")
        time.sleep(0.01)


def _orders(bus: StatusBus, names: list[str]) -> float:
    """ms per order: one ``publish_task`` to each of ``names``."""
    msgs = [TaskMessage(None, "idle", robot=n) for n in names]
    t0 = time.perf_counter()
    for m in msgs:
        bus.publish_task(m)
    return (time.perf_counter() - t0) / len(msgs) * 1e3


# long: one measurement, set-up to teardown, printed as it goes
def measure(robots: int, events: int) -> dict[str, float]:
    endpoint = free_endpoint()
    session = open_session(endpoint, "router")
    agents = StatusBus(session, max_events=0)
    names = [f"r{i}" for i in range(robots)]
    guard = agents.guard_orders(names, wildcard=True)
    handles = []
    for n in names:
        handles.append(agents.subscribe_tasks(n, lambda m: None))
        handles.append(agents.subscribe_grants(n, lambda g: None))
        handles.append(agents.declare_alive(n))
    service = TaskService(load_config(CONFIG), SimClock())
    face = ServiceBus(session, service)
    client = open_session(endpoint, "client", connect_timeout_s=30.0)
    out: dict[str, float] = {}
    try:
        out["before"] = _per_ms(_old_put(session, service), _events(events, 1))
        out["unwatched"] = _per_ms(face._on_event, _events(events, events + 1))
        got = [0]
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                got[0] += 1

        sub = client.declare_subscriber(f"{SERVICE_PREFIX}/events/**", on_sample)
        _wait(lambda: face.matching, "the face to see the subscriber")
        out["watched"] = _per_ms(face._on_event, _events(events, 2 * events + 1))
        _wait(lambda: got[0] >= events, f"{events} events at the subscriber")
        sub.undeclare()
        coordinator = StatusBus(session, max_events=0)
        out["orders_first_use"] = _orders(coordinator, names)
        coordinator.close()
        coordinator = StatusBus(session, max_events=0)
        t0 = time.perf_counter()
        coordinator.declare_task_publishers(names)
        out["declare_in_setup"] = (time.perf_counter() - t0) / robots * 1e3
        out["orders_declared"] = _orders(coordinator, names)
        coordinator.close()
    finally:
        face.close()
        for h in handles:
            h.undeclare()
        guard.undeclare()
        agents.close()
        close_session(client)
        close_session(session)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, nargs="+", default=[1000, 2000])
    p.add_argument("--events", type=int, default=2000, help="task events per variant (default 2000)")
    args = p.parse_args(argv)
    print(
        f"{'robots':>6} | {'event put before':>16} {'no subscriber':>13} {'watched':>8} "
        f"{'ratio':>7} | {'order 1st use':>13} {'declared':>8} {'ratio':>6} {'declare in set-up':>17}"
    )
    for n in args.robots:
        r = measure(n, args.events)
        print(
            f"{n:>6} | {r['before']:>13.4f} ms {r['unwatched'] * 1e3:>10.2f} us {r['watched']:>5.3f} ms "
            f"{r['before'] / r['unwatched']:>6.0f}x | {r['orders_first_use']:>10.4f} ms "
            f"{r['orders_declared']:>5.4f} ms {r['orders_first_use'] / r['orders_declared']:>5.1f}x "
            f"{r['declare_in_setup']:>14.4f} ms",
            flush=True,
        )
    print("(ms per event / per order; ratio = before / after, measured in this run)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
