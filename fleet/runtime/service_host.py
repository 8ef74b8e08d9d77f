"""What the coordinator's process serves besides the coordinator (``docs/service.md``): the
task service and its durable store (``--state DIR``), the fleet's control state and where it
goes (the e-stop latch, the agents, the bus), the Zenoh face and the HTTP API (``--api``).

:class:`ServiceHost` is built by the :class:`~fleet.runtime.runner.FleetRunner` when it runs
the coordinator; it never owns the loop: the runner calls :meth:`ServiceHost.tick` once per
agent tick (re-publishing the control state every :data:`CONTROL_REPUBLISH_S`).
"""

from __future__ import annotations

import datetime as dt
import logging
import os
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.errors import ConfigError
from fleet.messages import FleetControl
from fleet.runtime.closing import close_logged
from fleet.service.records import iso
from fleet.service.service import TaskService
from fleet.service.store import TaskStore

if TYPE_CHECKING:
    import zenoh

    from fleet.api.server import ApiServer
    from fleet.bus.lease import CoordinatorLease
    from fleet.bus.status_bus import StatusBus
    from fleet.config.model import FleetConfig
    from fleet.navigation import Clock
    from fleet.service.bus_face import ServiceBus
    from fleet.traffic.policy import ReservationTraffic

logger = logging.getLogger(__name__)

#: The control state is published again this often (fleet s), for processes that join late.
CONTROL_REPUBLISH_S = 1.0
#: Where runs keep their durable task book unless ``--state`` says otherwise.
DEFAULT_STATE_ROOT = Path("out") / "state"


def default_state_dir(config: FleetConfig) -> Path:
    """A new, empty ``out/state/<fleet>-<UTC time>-<pid>[-<n>]`` (the root may be moved with
    ``$FLEET_STATE_ROOT``): a new book per run (resume one with ``--state``). The directory is
    created here, so two runs started in the same second by one process never share (and so
    never resume) a book."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%d-%H%M%S")
    root = Path(os.environ.get("FLEET_STATE_ROOT") or DEFAULT_STATE_ROOT)
    root.mkdir(parents=True, exist_ok=True)
    base = f"{config.name}-{stamp}-{os.getpid()}"
    for n in range(1, 10_000):
        path = root / (base if n == 1 else f"{base}-{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise ConfigError(str(root), "state", "no new state directory could be made here")


def traffic_view(policy: ReservationTraffic) -> Callable[[], dict[str, Any]]:
    """``/api/traffic``: the nodes and edge segments every robot holds, with positions."""
    m = policy.manager

    def view() -> dict[str, Any]:
        segments: list[dict[str, Any]] = []
        nodes: list[dict[str, Any]] = []
        for robot in m.robots:
            for res in sorted(m.held(robot), key=str):
                if isinstance(res, tuple):
                    a, b = res
                    segments.append({"robot": robot, "a": list(m.node_pos(a)), "b": list(m.node_pos(b))})
                else:
                    x, y = m.node_pos(res)
                    nodes.append({"robot": robot, "name": res, "x": x, "y": y})
        return {"enabled": True, "segments": segments, "nodes": nodes}

    return view


class ServiceHost:
    """The task service of one coordinator and its faces (see the module docstring).

    Args:
        config: the fleet config.
        clock: the fleet clock.
        state_dir: the durable task book's directory (``None``: an in-memory book, nothing
            survives the process; the CLI passes :func:`default_state_dir` unless ``--state``).
        api: ``HOST:PORT`` to serve the HTTP API on (``None``: no HTTP).
        api_token: the bearer token the API requires for mutating calls (``None``: none;
            see :func:`fleet.api.app.create_app`).
    """

    def __init__(
        self,
        config: FleetConfig,
        clock: Clock,
        state_dir: Path | None,
        api: str | None,
        *,
        api_token: str | None = None,
    ) -> None:
        self.config = config
        self.api_address: tuple[str, int] | None = None
        if api is not None:
            from fleet.api.server import parse_address  # FastAPI and uvicorn only with an API

            try:
                self.api_address = parse_address(api)
            except ValueError as e:
                raise ConfigError(str(config.path), "api", str(e)) from None
        self.api_token = api_token
        self.state_dir = state_dir
        self.store = TaskStore(state_dir) if state_dir is not None else None
        self.service = TaskService(config, clock, self.store)
        self.bus: StatusBus | None = None
        self.api: ApiServer | None = None
        self.face: ServiceBus | None = None
        self._last_publish = -1e18

    @property
    def control(self) -> FleetControl:
        return self.service.control

    def start(self, session: zenoh.Session, bus: StatusBus) -> None:
        """Publish the control state on ``bus``, serve the Zenoh face and (``api``) the HTTP API."""
        from fleet.service.bus_face import ServiceBus

        self.bus = bus
        self.service.switch.add_sink(bus.publish_control)
        self.face = ServiceBus(session, self.service)
        if self.api_address is not None:
            from fleet.api.app import create_app
            from fleet.api.server import ApiServer

            host, port = self.api_address
            if self.api_token is not None and host not in ("127.0.0.1", "localhost", "::1"):
                logger.warning(
                    "the API on %s:%d takes the token for changes but its reads are open to the network",
                    host,
                    port,
                )
            self.api = ApiServer(create_app(self.service, token=self.api_token), host, port).start()

    def take_lease(self, session: zenoh.Session, endpoint: str) -> CoordinatorLease:
        """The coordinator lease with the next epoch after the durable book's (kept there);
        raises :class:`~fleet.errors.LeaseError` if another coordinator holds one."""
        from fleet.bus.lease import acquire_coordinator_lease, next_epoch

        store = self.service.store
        epoch = next_epoch(store.counter("epoch") if store is not None else 0)
        lease = acquire_coordinator_lease(session, epoch, endpoint)
        if store is not None:
            store.raise_counter("epoch", epoch)
        return lease

    def tick(self, now: float) -> None:
        """Re-publish the control state every :data:`CONTROL_REPUBLISH_S` fleet seconds."""
        if self.bus is not None and now - self._last_publish >= CONTROL_REPUBLISH_S:
            self._last_publish = now
            try:
                self.bus.publish_control(self.service.control)
            except Exception as e:  # noqa: BLE001 - the session may be closing
                logger.debug("publishing the control state: %s", e)

    def task_summary(self) -> dict[str, Any]:
        """Tasks by state and by kind, and the state directory (for the run report)."""
        recs = self.service.tasks()
        return {
            "state_dir": str(self.state_dir) if self.state_dir is not None else None,
            "total": len(recs),
            "by_state": dict(Counter(r.state.value for r in recs)),
            "by_kind": dict(Counter(r.kind for r in recs)),
        }

    def control_events(self) -> list[dict[str, Any]]:
        """Every control change of this run (and the one read back at start)."""
        out = []
        for c in self.service.switch.history:
            d = c.to_dict()
            d["at"] = iso(c.wall) if c.wall else None
            out.append(d)
        return out

    def close(self) -> None:
        """Stop the HTTP API and the Zenoh face; close the store."""
        closers: list[Callable[[], None]] = []
        if self.api is not None:
            closers.append(self.api.stop)
        if self.face is not None:
            closers.append(self.face.close)
        for close in closers:
            close_logged(close, "closing the task service", logger)
        self.api = None
        self.face = None
        if self.store is not None:
            self.store.close()
