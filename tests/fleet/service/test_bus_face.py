"""The task service on the Zenoh bus alone: queryables answer tasks, robots and the control
state, take submissions, cancels and commands (errors as JSON naming the field), and every
task event is published under ``fleet/service/events/<id>``."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from typing import Any

import zenoh
from conftest import PATROL, LiveFleet, wait_for
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.service.bus_face import ServiceBus
from fleet.service.service import TaskService


def query(session: zenoh.Session, key: str, payload: Any = None) -> tuple[bool, Any]:
    """``(ok, decoded JSON)`` of the one reply to ``key``."""
    kw: dict[str, Any] = {"timeout": 30.0}
    if payload is not None:
        kw["payload"] = json.dumps(payload)
    replies = list(session.get(key, **kw))
    assert len(replies) == 1, key
    r = replies[0]
    if r.ok is not None:
        return True, json.loads(r.ok.payload.to_bytes())
    assert r.err is not None
    return False, json.loads(r.err.payload.to_bytes())


def test_queryables_and_events(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=True)
    session = open_session(fleet.runner.endpoint, "client", connect_timeout_s=30.0)
    events: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_event(sample: zenoh.Sample) -> None:
        with lock:
            events.append(json.loads(sample.payload.to_bytes()))

    sub = session.declare_subscriber("fleet/service/events/**", on_event)
    try:
        ok, tasks = query(session, "fleet/service/tasks")
        assert ok and isinstance(tasks, list)
        ok, err = query(session, "fleet/service/submit", {"kind": "go_to", "target": "nowhere"})
        assert not ok and err["status"] == 422 and err["field"] == "target"
        ok, err = query(session, "fleet/service/submit", None)
        assert not ok and err["status"] == 422 and err["field"] == "kind"
        assert [x["id"] for x in query(session, "fleet/service/tasks")[1]] == [
            x["id"] for x in tasks
        ]  # none stored
        ok, t = query(session, "fleet/service/submit", {"kind": "go_to", "target": "a2_n"})
        assert ok and t["state"] == "queued"
        wait_for(
            lambda: query(session, f"fleet/service/tasks/{t['id']}")[1]["state"] == "completed", "completed"
        )
        with lock:
            mine = [e["event"]["state"] for e in events if e["event"]["task_id"] == t["id"]]
        for s in ("queued", "assigned", "active", "completed"):
            assert s in mine, mine
        ok, robots = query(session, "fleet/service/robots")
        assert ok and len(robots) == 4 and all("battery" in r for r in robots)
        ok, ctl = query(session, "fleet/service/command/pause", {"by": "bus test"})
        assert ok and ctl["state"] == "paused" and ctl["by"] == "bus test"
        ok, err = query(session, "fleet/service/command/dance")
        assert not ok and err["status"] == 422
        ok, t2 = query(session, "fleet/service/submit", {"kind": "go_to", "target": "a4_n"})
        ok, c = query(session, f"fleet/service/cancel/{t2['id']}")
        assert ok and (c["state"] == "canceled" or c["cancel_requested"])  # the bus face does not wait
        wait_for(
            lambda: query(session, f"fleet/service/tasks/{t2['id']}")[1]["state"] == "canceled", "canceled"
        )
        ok, err = query(session, "fleet/service/cancel/t-9999")
        assert not ok and err["status"] == 404
    finally:
        sub.undeclare()
        session.close()


def test_events_go_out_only_while_a_subscriber_matches() -> None:
    """No subscriber on ``fleet/service/events/*``: events are counted, not put (a put costs
    time in proportion to the session's subscriptions). A subscriber on another session, through
    the router, receives every event from once the service has heard of it, and none after it
    leaves."""
    endpoint = free_endpoint()
    router = open_session(endpoint, "router")
    service = TaskService(load_config(PATROL), SimClock())
    face = ServiceBus(router, service)
    client = open_session(endpoint, "client", connect_timeout_s=30.0)
    got: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_event(sample: zenoh.Sample) -> None:
        with lock:
            got.append(json.loads(sample.payload.to_bytes()))

    try:
        t1 = service.submit({"kind": "go_to", "target": "a2_n"}, by="test")
        assert (face.unsent, face.sent) == (1, 0)
        sub = client.declare_subscriber("fleet/service/events/**", on_event)
        wait_for(lambda: face.matching, "the service hears of the subscriber")
        t2 = service.submit({"kind": "go_to", "target": "a4_n"}, by="test")
        wait_for(lambda: len(got) == 1, "the second task's event")
        with lock:
            assert got[0]["event"]["task_id"] == t2.id and got[0]["task"]["id"] == t2.id
            assert got[0]["event"]["event"] == "queued"
        assert (face.unsent, face.sent) == (1, 1) and t1.id != t2.id
        later = ServiceBus(router, service)  # a face declared after the subscriber sees it at once
        assert later.matching
        later.close()
        sub.undeclare()
        wait_for(lambda: not face.matching, "the service hears the subscriber left")
        service.submit({"kind": "go_to", "target": "a2_n"}, by="test")
        assert (face.unsent, face.sent) == (2, 1)
    finally:
        face.close()
        client.close()
        router.close()
