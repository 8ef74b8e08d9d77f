"""The HTTP API's mutating endpoints and the task service's bus face refuse hostile and
malformed bodies (property-based, on a live fleet's real API and Zenoh queryables): garbage bytes, truncated and deeply nested JSON, wrong types, NaN /
infinity, huge numbers and bodies over the size limit are answered 400 / 413 / 422, counted
(``TaskService.bad_requests``, in the run report's ``malformed_messages``) and change nothing:
no task is stored, the fleet is neither paused nor stopped (docs/protocol.md)."""

from __future__ import annotations

import json
from collections.abc import Callable

from conftest import LiveFleet
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.api.app import MAX_BODY
from fleet.bus.session import open_session

#: Valid bodies the garbage is made from: a task submission and a fleet command.
TASK = {"kind": "go_to", "target": "a2_n", "priority": 1}
COMMAND = {"by": "tester", "reason": "fuzz"}
PATHS = ["/api/tasks", "/api/fleet/pause", "/api/fleet/estop", "/api/fleet/resume", "/api/fleet/release"]


def _with(valid: dict[str, object], name: str, raw: bytes) -> bytes:
    marker = "\u0000FUZZ\u0000"
    return json.dumps({**valid, name: marker}).encode().replace(json.dumps(marker).encode(), raw)


def _not_an_object(b: bytes) -> bool:
    if not b.strip():
        return False  # an empty command body is a valid command
    try:
        return not isinstance(json.loads(b), dict)
    except (ValueError, RecursionError):
        return True


def garbage(valid: dict[str, object]) -> st.SearchStrategy[bytes]:
    text = json.dumps(valid).encode()
    fields = st.sampled_from(sorted(valid))
    return st.one_of(
        st.binary(min_size=1, max_size=64).filter(_not_an_object),
        st.integers(1, len(text) - 1).map(lambda n: text[:n]),
        st.tuples(fields, st.integers(100, 20000)).map(
            lambda fd: _with(valid, fd[0], b"[" * fd[1] + b"]" * fd[1])
        ),
        fields.map(lambda f: _with(valid, f, b'{"wrong": "type"}')),
        st.tuples(fields, st.sampled_from([b"NaN", b"Infinity", b"-1e999"])).map(
            lambda fv: _with(valid, *fv)
        ),
        st.just(_with(valid, "priority" if "priority" in valid else "reason", b"1" + b"0" * 40)),
        st.integers(MAX_BODY + 1, MAX_BODY + 4096).map(lambda n: _with(valid, "by", b'"' + b"x" * n + b'"')),
    )


def test_garbage_bodies_are_refused_counted_and_change_nothing(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=False, robots=2)
    assert fleet.runner.host is not None
    service = fleet.runner.host.service
    tasks = [t["id"] for t in fleet.http.get("/api/tasks").json()]
    control = fleet.http.get("/api/fleet").json()["control"]

    @settings(max_examples=40, deadline=None, derandomize=True)
    @given(data=st.data())
    def one(data: st.DataObject) -> None:
        path = data.draw(st.sampled_from(PATHS), label="path")
        body = data.draw(garbage(TASK if path == "/api/tasks" else COMMAND), label="body")
        before = service.bad_requests
        r = fleet.http.post(path, content=body, headers={"content-type": "application/json"})
        assert r.status_code in (400, 413, 422), (r.status_code, r.text)
        assert service.bad_requests == before + 1

    one()
    assert [t["id"] for t in fleet.http.get("/api/tasks").json()] == tasks  # nothing stored
    now = fleet.http.get("/api/fleet").json()["control"]
    assert (now["state"], now["seq"]) == (control["state"], control["seq"]) and now["state"] == "running"
    report = fleet.stop()
    assert report.malformed_messages >= 40


def test_garbage_queries_to_the_bus_face_are_refused_counted_and_change_nothing(
    live: Callable[..., LiveFleet],
) -> None:
    fleet = live(traffic=False, robots=2)
    assert fleet.runner.host is not None and fleet.runner.host.face is not None
    face = fleet.runner.host.face
    tasks = [t["id"] for t in fleet.http.get("/api/tasks").json()]
    session = open_session(fleet.runner.endpoint, "client", connect_timeout_s=30.0)
    try:

        @settings(max_examples=30, deadline=None, derandomize=True)
        @given(data=st.data())
        def one(data: st.DataObject) -> None:
            key = data.draw(
                st.sampled_from(["fleet/service/submit", "fleet/service/command/pause"]), label="key"
            )
            body = data.draw(garbage(TASK if key.endswith("submit") else COMMAND), label="body")
            before = face.malformed
            replies = list(session.get(key, payload=body, timeout=30.0))
            assert len(replies) == 1 and replies[0].err is not None
            err = json.loads(replies[0].err.payload.to_bytes())
            assert err["status"] in (400, 422), err
            assert face.malformed == before + 1

        one()
    finally:
        session.close()  # type: ignore[no-untyped-call]
    assert [t["id"] for t in fleet.http.get("/api/tasks").json()] == tasks
    assert fleet.http.get("/api/fleet").json()["control"]["state"] == "running"
