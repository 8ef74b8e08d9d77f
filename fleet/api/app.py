"""The HTTP + WebSocket face of the task service (FastAPI): ``create_app(service)``.

Endpoints (JSON; the OpenAPI schema is served at ``/openapi.json``, interactive docs at
``/docs``; contracts in ``docs/service.md``):

* ``POST /api/tasks`` submit a task (201, the task, state ``queued``); ``GET /api/tasks``
  (``?state=&kind=&robot=&limit=``) a list; ``GET /api/tasks/{id}`` one, with its latest
  events; ``GET /api/tasks/{id}/events``; ``POST /api/tasks/{id}/cancel``;
* ``GET /api/robots``; ``GET /api/fleet`` (control state, its history, counts);
  ``POST /api/fleet/pause|resume|estop|release`` (body ``{"by", "reason"}`` optional;
  ``X-Fleet-User`` header names who otherwise);
* the site for a dashboard: ``GET /api/map`` (metadata), ``/api/map.png``, ``/api/roadmap``,
  ``/api/chargers``, ``/api/stations``, ``/api/routes``, ``/api/parking``,
  ``/api/reservations`` (reserved nodes and segments when traffic management is on);
* ``/api/ws``: a WebSocket streaming robot states ``ws_hz`` times a second, task events and
  control changes as they happen (message shapes in ``docs/service.md``);
* ``/``: whatever the extensions mount (:func:`extend`): by default the package named by
  :data:`DASHBOARD_PACKAGE`, if installed, gets ``mount(app)`` called after every API route
  is added (the live dashboard serves its static files there); without one, ``/`` is a small
  page pointing at ``/docs``.

Bad input gets a 4xx answer ``{"error", "field", "status"}`` and changes nothing: invalid
JSON 400, a body over ``max_body`` bytes 413, an invalid task 422, an unknown task 404, a
cancel of a finished task or ``resume`` while the e-stop is latched 409. A secured fleet
(``token``) answers a mutating call without the right bearer token 401 (:mod:`fleet.api.auth`).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import json
import logging
from collections import Counter
from collections.abc import Awaitable, Callable, MutableMapping, Sequence
from typing import Any, Literal

from fastapi import FastAPI, Header, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse, Response
from pydantic import ValidationError

from fleet.api import schemas
from fleet.api.auth import TokenGuard
from fleet.errors import CommandRefused, InvalidTask, ServiceError, TaskFinished, UnknownTask
from fleet.messages import FleetControl
from fleet.service import site
from fleet.service.records import TaskEvent, iso
from fleet.service.service import TaskService
from fleet.service.specs import TASK_SPEC, explain_errors

logger = logging.getLogger(__name__)

#: The package whose ``mount(app: FastAPI) -> None`` extends the app by default (the dashboard).
DASHBOARD_PACKAGE = "fleet.dashboard"
#: Request bodies larger than this (bytes) are refused with 413.
MAX_BODY = 64 * 1024
#: Robot states per second on ``/api/ws``.
WS_HZ = 10.0
#: Events waiting for a slow WebSocket client beyond this many are dropped (oldest kept).
WS_QUEUE = 10_000

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


def error(status: int, reason: str, field: str = "") -> JSONResponse:
    """The JSON body of every 4xx answer."""
    return JSONResponse({"error": reason, "field": field, "status": status}, status_code=status)


class BodyLimit:
    """ASGI middleware: a request whose body is larger than ``limit`` bytes gets 413 before
    anything reads it (by its Content-Length, or while it streams in)."""

    def __init__(self, app: ASGIApp, limit: int, on_reject: Callable[[], None] = lambda: None) -> None:
        self.app = app
        self.limit = limit
        self.on_reject = on_reject

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for k, v in scope.get("headers", []):
            if k == b"content-length" and v.isdigit() and int(v) > self.limit:
                self.on_reject()
                await error(413, f"request body of {int(v)} bytes is larger than {self.limit}")(
                    scope, receive, send
                )
                return
        seen = 0

        async def limited() -> MutableMapping[str, Any]:
            nonlocal seen
            msg = await receive()
            seen += len(msg.get("body", b""))
            if seen > self.limit:
                raise _TooLarge()
            return msg

        try:
            await self.app(scope, limited, send)
        except _TooLarge:
            self.on_reject()
            await error(413, f"request body larger than {self.limit} bytes")(scope, receive, send)


class _TooLarge(Exception):
    pass


def control_dict(ctl: FleetControl) -> dict[str, Any]:
    d = ctl.to_dict()
    d["at"] = iso(ctl.wall) if ctl.wall else None
    return d


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` for these error codes (all :class:`~fleet.api.schemas.ErrorOut`)."""
    return {c: {"model": schemas.ErrorOut} for c in codes}


def who(by: str | None, header: str | None, request: Request | WebSocket) -> str:
    if by:
        return by
    if header:
        return header[:256]
    host = request.client.host if request.client is not None else "?"
    return f"api {host}"


# long: one route per endpoint, each a few lines, so the API reads in one place
def create_app(
    service: TaskService,
    *,
    extensions: Sequence[Callable[[FastAPI], None]] | None = None,
    max_body: int = MAX_BODY,
    ws_hz: float = WS_HZ,
    token: str | None = None,
) -> FastAPI:
    """The API of ``service`` (see the module docstring). ``extensions`` are called with the
    app once every API route is added (default: :func:`default_extensions`). With ``token``
    every mutating call needs ``Authorization: Bearer <token>`` (:mod:`fleet.api.auth`)."""
    config = service.config
    app = FastAPI(
        title=f"fleet task service: {config.name}",
        version="1",
        description="Tasks, robots and fleet control of a running fleet. See docs/service.md.",
    )
    app.state.service = service
    png: dict[str, bytes] = {}

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        e = explain_errors(list(exc.errors()))
        service.bad_requests += 1
        status = 400 if e.reason.startswith("invalid JSON") else 422
        return error(status, e.reason, e.field)

    @app.exception_handler(ServiceError)
    async def _service_error(request: Request, exc: ServiceError) -> JSONResponse:
        if isinstance(exc, InvalidTask):
            service.bad_requests += 1
            return error(400 if exc.reason.startswith("invalid JSON") else 422, exc.reason, exc.field)
        if isinstance(exc, UnknownTask):
            return error(404, str(exc), "id")
        if isinstance(exc, (TaskFinished, CommandRefused)):
            return error(409, str(exc))
        return error(400, str(exc))

    bad = errors(400, 413, 422)

    @app.post(
        "/api/tasks",
        status_code=201,
        response_model=schemas.TaskOut,
        responses=bad,
        tags=["tasks"],
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {"application/json": {"schema": {"$ref": "#/components/schemas/TaskSpec"}}},
            }
        },
    )
    async def submit(request: Request, x_fleet_user: str | None = Header(None)) -> JSONResponse:
        """Submit a task: ``{"kind": ..., <its arguments>, "priority"?, "robot"?, "name"?}``
        (the body is read as JSON whatever its Content-Type)."""
        data = json_body(await request.body())
        rec = service.submit(data, by=x_fleet_user or "api")
        return JSONResponse(rec.to_dict(), status_code=201)

    @app.get("/api/tasks", response_model=list[schemas.TaskOut], tags=["tasks"])
    async def tasks(
        state: schemas.TaskStateName | None = None,
        kind: str | None = None,
        robot: str | None = None,
        limit: int | None = None,
    ) -> JSONResponse:
        """Every task (oldest first), filtered; ``limit``: the latest so many."""
        return JSONResponse([r.to_dict() for r in service.tasks(state, kind, robot, limit)])

    @app.get(
        "/api/tasks/{task_id}",
        response_model=schemas.TaskOut,
        responses=errors(404),
        tags=["tasks"],
    )
    async def task(task_id: str) -> JSONResponse:
        """One task, with its latest 50 events."""
        d = service.get(task_id).to_dict()
        d["events"] = [e.to_dict() for e in service.events(task_id, 50)]
        return JSONResponse(d)

    @app.get("/api/tasks/{task_id}/events", response_model=list[schemas.TaskEventOut], tags=["tasks"])
    async def task_events(task_id: str, limit: int = 100) -> JSONResponse:
        service.get(task_id)
        return JSONResponse([e.to_dict() for e in service.events(task_id, max(1, min(limit, 10_000)))])

    @app.post(
        "/api/tasks/{task_id}/cancel",
        response_model=schemas.TaskOut,
        responses=errors(404, 409),
        tags=["tasks"],
    )
    async def cancel(task_id: str, x_fleet_user: str | None = Header(None)) -> JSONResponse:
        """Cancel a queued or held task (a held one is taken from its robot, which stops)."""
        rec = await asyncio.to_thread(service.cancel, task_id, x_fleet_user or "api")
        return JSONResponse(rec.to_dict())

    @app.get("/api/robots", response_model=list[schemas.RobotOut], tags=["robots"])
    async def robots() -> JSONResponse:
        return JSONResponse(service.robots())

    @app.get("/api/fleet", response_model=schemas.FleetOut, tags=["fleet"])
    async def fleet() -> JSONResponse:
        counts = Counter(r.state.value for r in service.tasks())
        return JSONResponse(
            {
                "name": config.name,
                "control": control_dict(service.control),
                "history": [control_dict(c) for c in service.switch.history],
                "robots": len(config.robots),
                "tasks": dict(counts),
                "traffic": bool(service.views.get("traffic_enabled", lambda: False)()),
                "t": float(service.clock.now()),
            }
        )

    def command(action: Literal["pause", "resume", "estop", "release"]) -> Any:
        async def run(request: Request, x_fleet_user: str | None = Header(None)) -> JSONResponse:
            body = await request.body()
            args = schemas.CommandIn(by=None, reason=None)
            if body.strip():
                try:
                    args = schemas.CommandIn.model_validate(json_body(body))
                except ValidationError as e:
                    raise explain_errors(list(e.errors(include_url=False))) from None
            ctl = service.command(action, who(args.by, x_fleet_user, request), args.reason or "")
            return JSONResponse(control_dict(ctl))

        run.__doc__ = {
            "pause": "Robots stop where they are and keep their tasks.",
            "resume": "Robots carry on with their tasks (refused while the e-stop is latched).",
            "estop": "Emergency stop: every robot stops within one simulator step, latched until release.",
            "release": "Unlatch the e-stop; the fleet stays paused until resume.",
        }[action]
        return run

    for action in ("pause", "resume", "estop", "release"):
        app.post(
            f"/api/fleet/{action}",
            response_model=schemas.ControlOut,
            responses=errors(409, 422),
            tags=["fleet"],
            name=action,
            openapi_extra={
                "requestBody": {
                    "content": {"application/json": {"schema": schemas.CommandIn.model_json_schema()}}
                }
            },
        )(command(action))

    @app.get("/api/map", response_model=schemas.MapOut, tags=["site"])
    async def map_meta() -> JSONResponse:
        return JSONResponse(site.map_info(config))

    @app.get(
        "/api/map.png",
        tags=["site"],
        responses={200: {"content": {"image/png": {}}}},
        response_class=Response,
    )
    async def map_image() -> Response:
        """The map image (one pixel per cell, top row first). Its placement is in ``/api/map``
        and in the headers ``X-Map-Resolution`` (m per pixel) and ``X-Map-Origin`` (``x,y`` of
        the lower-left corner, m)."""
        if "png" not in png:
            png["png"] = await asyncio.to_thread(site.map_png, config.grid)
        g = config.grid
        headers = {"X-Map-Resolution": f"{g.resolution:g}", "X-Map-Origin": f"{g.origin_x:g},{g.origin_y:g}"}
        return Response(png["png"], media_type="image/png", headers=headers)

    @app.get("/api/roadmap", response_model=schemas.RoadmapOut, tags=["site"])
    async def roadmap() -> JSONResponse:
        return JSONResponse(site.roadmap_dict(config))

    @app.get("/api/chargers", response_model=list[schemas.NamedPoseOut], tags=["site"])
    async def chargers() -> JSONResponse:
        return JSONResponse(site.chargers(config))

    @app.get("/api/stations", response_model=list[schemas.NamedPoseOut], tags=["site"])
    async def stations() -> JSONResponse:
        return JSONResponse(site.stations(config))

    @app.get("/api/routes", tags=["site"])
    async def routes() -> JSONResponse:
        return JSONResponse(site.routes(config))

    @app.get("/api/parking", response_model=list[schemas.NamedPoseOut], tags=["site"])
    async def parking() -> JSONResponse:
        return JSONResponse(site.parking(config))

    @app.get("/api/reservations", response_model=schemas.TrafficOut, tags=["site"])
    @app.get("/api/traffic", response_model=schemas.TrafficOut, tags=["site"], include_in_schema=False)
    async def traffic() -> JSONResponse:
        """Roadmap nodes and segments each robot holds (``enabled`` false without traffic management)."""
        view = service.views.get("traffic")
        return JSONResponse(view() if view is not None else {"enabled": False, "segments": [], "nodes": []})

    @app.websocket("/api/ws")
    async def ws(websocket: WebSocket) -> None:
        await stream(websocket, service, ws_hz)

    app.openapi = lambda: openapi(app)  # type: ignore[method-assign]
    extend(app, default_extensions() if extensions is None else extensions)
    inner = app.build_middleware_stack

    def build() -> ASGIApp:
        limited: ASGIApp = BodyLimit(
            inner(), max_body, lambda: setattr(service, "bad_requests", service.bad_requests + 1)
        )
        return limited if token is None else TokenGuard(limited, token)

    app.build_middleware_stack = build  # type: ignore[method-assign]
    return app


def json_body(body: bytes) -> Any:
    """The request body parsed as JSON; :class:`InvalidTask` (400) if it is empty or invalid."""
    if not body.strip():
        raise InvalidTask("", "invalid JSON: the body is empty (expected a JSON object)")
    try:
        return json.loads(body)
    except RecursionError:
        raise InvalidTask("", "invalid JSON: nested too deeply") from None
    except ValueError as e:
        raise InvalidTask("", f"invalid JSON: {e}") from None


def openapi(app: FastAPI) -> dict[str, Any]:
    """FastAPI's schema plus ``TaskSpec`` (the body of ``POST /api/tasks``) in its components."""
    if app.openapi_schema is None:
        schema = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        spec = TASK_SPEC.json_schema(ref_template="#/components/schemas/{model}")
        comps = schema.setdefault("components", {}).setdefault("schemas", {})
        comps.update(spec.pop("$defs", {}))
        comps["TaskSpec"] = spec
        app.openapi_schema = schema
    return app.openapi_schema


def default_extensions() -> list[Callable[[FastAPI], None]]:
    """``[mount]`` of the :data:`DASHBOARD_PACKAGE` package if it is installed, else ``[]``."""
    try:
        mod = importlib.import_module(DASHBOARD_PACKAGE)
    except ImportError:
        return []
    mount = getattr(mod, "mount", None)
    return [mount] if callable(mount) else []


def extend(app: FastAPI, extensions: Sequence[Callable[[FastAPI], None]]) -> None:
    """Call every extension with ``app`` (they add routes or mount static files; the API
    routes, added before, keep priority). If none serves ``/``, ``/`` is a small page that
    points at the API docs."""
    for ext in extensions:
        ext(app)
    if any(getattr(r, "path", None) in ("/", "") for r in app.router.routes):
        return

    @app.get("/", include_in_schema=False)
    async def index() -> HTMLResponse:
        return HTMLResponse(
            "<!doctype html><title>fleet</title><h1>fleet task service</h1>"
            '<p>API: <a href="/docs">/docs</a>, schema <a href="/openapi.json">/openapi.json</a></p>'
        )


def _message(ev: TaskEvent | FleetControl, service: TaskService) -> dict[str, Any]:
    if isinstance(ev, FleetControl):
        return {"type": "fleet", "control": control_dict(ev)}
    rec = service.records.get(ev.task_id)
    return {"type": "task", "event": ev.to_dict(), "task": rec.to_dict() if rec is not None else None}


async def stream(websocket: WebSocket, service: TaskService, ws_hz: float) -> None:
    """``/api/ws``: a ``hello`` (fleet, control, every task), then robot states ``ws_hz``
    times a second, task events and control changes as they happen (see ``docs/service.md``)."""
    await websocket.accept()
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[TaskEvent | FleetControl] = asyncio.Queue(maxsize=WS_QUEUE)

    def put(ev: TaskEvent | FleetControl) -> None:
        with contextlib.suppress(asyncio.QueueFull):
            queue.put_nowait(ev)

    def on_event(ev: TaskEvent | FleetControl) -> None:
        loop.call_soon_threadsafe(put, ev)

    stop = service.subscribe(on_event)
    period = 1.0 / ws_hz
    try:
        await websocket.send_text(
            json.dumps(
                {
                    "type": "hello",
                    "fleet": service.config.name,
                    "control": control_dict(service.control),
                    "tasks": [r.to_dict() for r in service.tasks()],
                    "robots_hz": ws_hz,
                }
            )
        )
        next_t = loop.time()
        while True:
            wait = next_t - loop.time()
            if wait > 0:
                with contextlib.suppress(TimeoutError):
                    ev = await asyncio.wait_for(queue.get(), wait)
                    await websocket.send_text(json.dumps(_message(ev, service)))
                    while not queue.empty():
                        await websocket.send_text(json.dumps(_message(queue.get_nowait(), service)))
                continue
            robots = service.robots()
            await websocket.send_text(
                json.dumps({"type": "robots", "t": float(service.clock.now()), "robots": robots})
            )
            next_t = max(next_t + period, loop.time())
            traffic = service.views.get("traffic")
            if traffic is not None:
                await websocket.send_text(json.dumps({"type": "traffic", **traffic()}))
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass
    finally:
        stop()
