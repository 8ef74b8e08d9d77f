"""The task service on the Zenoh bus alone: queryables answer tasks, robots and the control
state, take submissions, cancels and commands (errors as JSON naming the field), and every
task event is published under ``fleet/service/events/<id>``."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from typing import Any

import zenoh
from conftest import LiveFleet, wait_for

from fleet.bus.session import open_session


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
