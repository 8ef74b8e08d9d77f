"""The Zenoh face of the task service: queryables and task-event publications under the
fleet's key space, so that processes on the bus need no HTTP (``docs/service.md``).

Queryables (``session.get(key)``; replies are JSON, errors ``{"error", "field", "status"}``
as ``reply_err``):

* ``fleet/service/tasks`` every task (selector parameters ``state``, ``kind``, ``robot``,
  ``limit``: ``fleet/service/tasks?state=active``); ``fleet/service/tasks/<id>`` one task;
* ``fleet/service/robots``; ``fleet/service/fleet`` the control state;
* ``fleet/service/submit`` (the task's JSON as the query payload) -> the stored task;
* ``fleet/service/cancel/<id>`` -> the task; ``fleet/service/command/<pause|resume|estop|
  release>`` (payload ``{"by", "reason"}`` optional) -> the control state.

Publications: every task event on ``fleet/service/events/<task id>`` (``{"event": ...,
"task": ...}``, the shapes of ``/api/ws``) while a subscriber matches those keys. One publisher
declared on ``fleet/service/events/*`` reports, through a matching listener, whether any
subscriber on the bus matches; while none does, events are counted (:attr:`ServiceBus.unsent`)
and not sent. (An undeclared put costs time in proportion to the subscriptions the session
holds, 0.5 ms at 2000 in-process agents, and a fleet's first assignment makes thousands of
events: ``bench/bench_task_events.py``.) A subscriber sees the events from the moment the
service learns of it (a few ms); earlier ones are in ``fleet/service/tasks/<id>`` and the
HTTP API's ``/api/tasks/<id>/events``. The control state itself travels on
``fleet/control/state`` (published by the coordinator's runner).

Malformed queries are answered with an error and counted (:attr:`ServiceBus.malformed`);
nothing raises into Zenoh's threads.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qsl

import zenoh

from fleet.bus.keys import SERVICE_EVENTS, SERVICE_PREFIX
from fleet.bus.session import Declaration, undeclare_all
from fleet.errors import CommandRefused, InvalidTask, ServiceError, TaskFinished, UnknownTask
from fleet.messages import FleetControl
from fleet.service.records import TaskEvent, iso
from fleet.service.service import TaskService

logger = logging.getLogger(__name__)

#: Query payloads larger than this (bytes) are refused.
MAX_QUERY_BYTES = 64 * 1024

Handler = Callable[[str, dict[str, str], bytes], Any]


def _status(e: ServiceError) -> tuple[int, str]:
    if isinstance(e, InvalidTask):
        return 422, e.field
    if isinstance(e, UnknownTask):
        return 404, "id"
    if isinstance(e, (TaskFinished, CommandRefused)):
        return 409, ""
    return 400, ""


def control_json(ctl: FleetControl) -> dict[str, Any]:
    d = ctl.to_dict()
    d["at"] = iso(ctl.wall) if ctl.wall else None
    return d


class ServiceBus:
    """Serves ``service`` on ``session`` (see the module docstring); :meth:`close` undeclares."""

    def __init__(self, session: zenoh.Session, service: TaskService) -> None:
        self.session = session
        self.service = service
        self.malformed = 0
        #: Task events not sent because no subscriber matched ``fleet/service/events/*``.
        self.unsent = 0
        #: Task events sent.
        self.sent = 0
        self._lock = threading.Lock()
        # a matching listener keeps this current: asking the publisher's matching status on
        # each event costs as much as the put it would save
        self._matching = False
        self._heard = False  # the listener has spoken: its word beats the first reading
        self._events_pub = session.declare_publisher(SERVICE_EVENTS)
        self._matching_listener = self._events_pub.declare_matching_listener(self._on_matching)
        first = self._matching_now()  # a subscriber already there
        with self._lock:
            if not self._heard:
                self._matching = first
        p = SERVICE_PREFIX
        routes: dict[str, Handler] = {
            f"{p}/tasks": self._tasks,
            f"{p}/tasks/*": self._task,
            f"{p}/robots": lambda k, q, b: service.robots(),
            f"{p}/fleet": lambda k, q, b: control_json(service.control),
            f"{p}/submit": self._submit,
            f"{p}/cancel/*": self._cancel,
            f"{p}/command/*": self._command,
        }
        self._decls: list[Declaration] = [
            session.declare_queryable(key, self._handler(h)) for key, h in routes.items()
        ]
        self._stop = service.subscribe(self._on_event)

    def _handler(self, fn: Handler) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            key = str(query.key_expr)
            try:
                # a client that subscribed to the events and then asks (e.g. submits) must see
                # the events its request causes: its subscription reached this session before
                # its query did, but the matching listener may not have spoken yet
                if not self._matching:
                    self._matching = self._matching_now()
                params = dict(parse_qsl(str(query.parameters)))
                payload = query.payload.to_bytes() if query.payload is not None else b""
                if len(payload) > MAX_QUERY_BYTES:
                    raise InvalidTask("", f"payload of {len(payload)} bytes is larger than {MAX_QUERY_BYTES}")
                out = fn(key, params, payload)
                query.reply(key, json.dumps(out))
            except ServiceError as e:
                status, field = _status(e)
                self._count()
                query.reply_err(json.dumps({"error": str(e), "field": field, "status": status}))
            except Exception as e:  # noqa: BLE001 - never raise into Zenoh's thread
                self._count()
                logger.warning("%s: %s", key, e)
                try:
                    query.reply_err(json.dumps({"error": f"internal: {e}", "field": "", "status": 500}))
                except Exception:  # noqa: BLE001
                    pass

        return on_query

    def _count(self) -> None:
        with self._lock:
            self.malformed += 1

    @staticmethod
    def _json(payload: bytes) -> Any:
        try:
            return json.loads(payload) if payload.strip() else {}
        except (ValueError, RecursionError) as e:
            raise InvalidTask("", f"invalid JSON: {e}") from None

    def _tasks(self, key: str, q: dict[str, str], payload: bytes) -> Any:
        limit = q.get("limit")
        if limit is not None and not limit.isdigit():
            raise InvalidTask("limit", f"expected a whole number, got {limit!r}")
        recs = self.service.tasks(
            q.get("state"), q.get("kind"), q.get("robot"), int(limit) if limit else None
        )
        return [r.to_dict() for r in recs]

    def _task(self, key: str, q: dict[str, str], payload: bytes) -> Any:
        return self.service.get(key.rsplit("/", 1)[-1]).to_dict()

    def _submit(self, key: str, q: dict[str, str], payload: bytes) -> Any:
        by = q.get("by") or "bus"
        return self.service.submit(self._json(payload), by=by).to_dict()

    def _cancel(self, key: str, q: dict[str, str], payload: bytes) -> Any:
        # no waiting here (Zenoh's callback thread): the answer may say cancel_requested
        return self.service.cancel(key.rsplit("/", 1)[-1], by=q.get("by") or "bus", wait_s=0.0).to_dict()

    def _command(self, key: str, q: dict[str, str], payload: bytes) -> Any:
        body = self._json(payload)
        if not isinstance(body, dict):
            raise InvalidTask("", "expected a JSON object")
        by, reason = body.get("by") or q.get("by") or "bus", body.get("reason") or ""
        if not isinstance(by, str) or not isinstance(reason, str):
            raise InvalidTask("by", "by and reason must be strings")
        return control_json(self.service.command(key.rsplit("/", 1)[-1], by, reason))

    @property
    def matching(self) -> bool:
        """Whether a subscriber on the bus matches ``fleet/service/events/*`` (events are sent)."""
        return self._matching

    def _matching_now(self) -> bool:
        """Ask the publisher (as costly as a put: not per event). Zenoh's stub calls the
        answer a bool; it is a ``MatchingStatus``."""
        status = self._events_pub.matching_status
        return bool(getattr(status, "matching", status))

    def _on_matching(self, status: zenoh.MatchingStatus) -> None:
        with self._lock:
            self._heard = True
            self._matching = bool(status.matching)

    def _on_event(self, ev: TaskEvent | FleetControl) -> None:
        if not isinstance(ev, TaskEvent):
            return
        if not self._matching:
            self.unsent += 1
            return
        rec = self.service.records.get(ev.task_id)
        msg = {"event": ev.to_dict(), "task": rec.to_dict() if rec is not None else None}
        try:
            self.session.put(f"{SERVICE_PREFIX}/events/{ev.task_id}", json.dumps(msg))
            self.sent += 1
        except Exception as e:  # noqa: BLE001 - the session may be closing
            logger.debug("publishing a task event: %s", e)

    def close(self) -> None:
        self._stop()
        undeclare_all([*self._decls, self._matching_listener, self._events_pub])
        self._decls = []
