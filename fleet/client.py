"""A small Python client for a running fleet's task service (``docs/service.md``), in the
spirit of nav2_simple_commander's ``BasicNavigator`` but for a fleet::

    fleet = FleetClient("http://127.0.0.1:8080")
    task = fleet.go_to("a3_n")
    task.wait(timeout=120)        # "completed"
    fleet.estop(reason="person in aisle 3")

Standard library only (``urllib``). Every call is one HTTP request with ``timeout`` wall
seconds; an answer with an error status raises :class:`~fleet.errors.ApiError` (its
``status``, ``field`` and ``reason`` from the API's JSON body); a fleet that cannot be reached
raises :class:`~fleet.errors.ApiError` with ``status`` 0.
"""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from collections.abc import Sequence
from typing import Any

from fleet.errors import ApiError

#: The task states that do not change any more.
FINAL_STATES = frozenset({"completed", "failed", "canceled"})


class TaskHandle:
    """One submitted task. :attr:`state` and friends read the latest answer (:meth:`refresh`
    asks again); :meth:`wait` polls until the task ends; :meth:`cancel` cancels it."""

    def __init__(self, client: FleetClient, data: dict[str, Any]) -> None:
        self.client = client
        self.data = data

    @property
    def id(self) -> str:
        return str(self.data["id"])

    @property
    def state(self) -> str:
        """``queued``, ``assigned``, ``active``, ``completed``, ``failed`` or ``canceled``."""
        return str(self.data["state"])

    @property
    def robot(self) -> str | None:
        r = self.data.get("robot")
        return None if r is None else str(r)

    @property
    def done(self) -> bool:
        return self.state in FINAL_STATES

    def refresh(self) -> TaskHandle:
        self.data = self.client.task(self.id)
        return self

    def wait(self, timeout: float | None = None, poll_s: float = 0.2) -> str:
        """Wait until the task ends (or ``timeout`` wall seconds pass); returns the state then
        (a state not in :data:`FINAL_STATES` means it timed out)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.refresh().done:
            if deadline is not None and time.monotonic() >= deadline:
                break
            time.sleep(poll_s)
        return self.state

    def cancel(self) -> str:
        """Cancel the task (a held one is taken from its robot); returns the state after it.
        :class:`~fleet.errors.ApiError` 409 if it had already ended."""
        self.data = self.client.request("POST", f"/api/tasks/{self.id}/cancel")
        return self.state

    def __repr__(self) -> str:
        return f"TaskHandle({self.id}, {self.data.get('kind')}, {self.state}, robot={self.robot})"


class FleetClient:
    """The task service at ``url`` (e.g. ``http://127.0.0.1:8080``); ``user`` is sent as
    ``X-Fleet-User`` (who submitted, who paused). ``token``: the API token of a secured fleet
    (the contents of ``DIR/api.token``), sent as ``Authorization: Bearer``; without it a
    secured fleet answers mutating calls with :class:`ApiError` status 401."""

    def __init__(
        self, url: str, *, user: str = "python", timeout: float = 30.0, token: str | None = None
    ) -> None:
        if "://" not in url:
            url = f"http://{url}"
        self.url = url.rstrip("/")
        self.user = user
        self.timeout = timeout
        self.token = token

    def request(self, method: str, path: str, body: Any = None) -> Any:
        """One request; the decoded JSON answer. :class:`ApiError` on an error status."""
        data = None if body is None else json.dumps(body).encode()
        headers = {"Content-Type": "application/json", "X-Fleet-User": self.user}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        req = urllib.request.Request(self.url + path, data=data, method=method, headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as resp:
                return json.loads(resp.read() or b"null")
        except urllib.error.HTTPError as e:
            try:
                err = json.loads(e.read())
            except ValueError:
                err = {}
            raise ApiError(e.code, str(err.get("error", e.reason)), str(err.get("field", ""))) from None
        except (urllib.error.URLError, OSError) as e:
            raise ApiError(0, f"cannot reach the fleet at {self.url}: {e}") from None

    # -- tasks ----------------------------------------------------------------------------

    def submit(self, spec: dict[str, Any]) -> TaskHandle:
        """Submit a task (``{"kind": ..., ...}``, see docs/service.md); its handle."""
        return TaskHandle(self, self.request("POST", "/api/tasks", spec))

    def go_to(self, target: str | Sequence[float], **extra: Any) -> TaskHandle:
        return self.submit({"kind": "go_to", "target": target, **extra})

    def patrol(
        self, waypoints: Sequence[str | Sequence[float]], laps: int | None = None, **extra: Any
    ) -> TaskHandle:
        spec: dict[str, Any] = {"kind": "patrol", "waypoints": list(waypoints), **extra}
        if laps is not None:
            spec["laps"] = laps
        return self.submit(spec)

    def pick(self, pickup: str | Sequence[float], dropoff: str | Sequence[float], **extra: Any) -> TaskHandle:
        return self.submit({"kind": "pick", "pickup": pickup, "dropoff": dropoff, **extra})

    def inspect(self, waypoints: Sequence[Any], action: str = "wait", **extra: Any) -> TaskHandle:
        return self.submit({"kind": "inspection", "waypoints": list(waypoints), "action": action, **extra})

    def task(self, task_id: str) -> dict[str, Any]:
        out: dict[str, Any] = self.request("GET", f"/api/tasks/{task_id}")
        return out

    def handle(self, task_id: str) -> TaskHandle:
        """A handle on a task submitted elsewhere."""
        return TaskHandle(self, self.task(task_id))

    def tasks(self, state: str | None = None) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = self.request("GET", "/api/tasks" + (f"?state={state}" if state else ""))
        return out

    # -- robots and the fleet ------------------------------------------------------------

    def robots(self) -> list[dict[str, Any]]:
        """Every robot: ``name``, ``state``, ``health``, ``battery``, ``pose`` ... ."""
        out: list[dict[str, Any]] = self.request("GET", "/api/robots")
        return out

    def fleet(self) -> dict[str, Any]:
        out: dict[str, Any] = self.request("GET", "/api/fleet")
        return out

    def command(self, action: str, reason: str = "") -> dict[str, Any]:
        """``pause``, ``resume``, ``estop`` or ``release``; the control state after it."""
        out: dict[str, Any] = self.request("POST", f"/api/fleet/{action}", {"reason": reason})
        return out

    def pause(self, reason: str = "") -> dict[str, Any]:
        return self.command("pause", reason)

    def resume(self, reason: str = "") -> dict[str, Any]:
        return self.command("resume", reason)

    def estop(self, reason: str = "") -> dict[str, Any]:
        return self.command("estop", reason)

    def release(self, reason: str = "") -> dict[str, Any]:
        return self.command("release", reason)
