"""Opening Zenoh sessions for the fleet: explicit endpoints, scouting off, a short lease.

One process *listens* on the endpoint in ``router`` mode (``fleet run``, ``fleet sim``); every
other process connects in ``client`` mode (a ``peer`` that does not listen receives nothing
through a router)."""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Iterable
from typing import Literal, Protocol

import zenoh

from fleet.errors import BusError

logger = logging.getLogger(__name__)


#: Default Zenoh link lease (s): a frozen peer is declared gone after this long.
DEFAULT_LEASE_S = 1.0


#: Default time (s) a client waits for its router when opening a session.
DEFAULT_CONNECT_TIMEOUT_S = 2.0


#: A client whose router went away tries to reconnect after this long (ms), backing off to
#: :data:`RECONNECT_MAX_MS`: measured with eclipse-zenoh 1.10.2 on loopback, a client was
#: connected again (its subscriptions, publishers and liveliness tokens re-declared by Zenoh)
#: within about 0.5 s of a restarted router listening, against 3.5 s with Zenoh's defaults.
RECONNECT_INIT_MS = 250
#: The longest wait (ms) between two reconnection attempts of a client.
RECONNECT_MAX_MS = 1000


Role = Literal["router", "client", "peer"]


_ENDPOINT_RE = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")


def zenoh_config(
    endpoint: str,
    role: Role,
    *,
    listen: bool,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    lease_s: float | None = DEFAULT_LEASE_S,
) -> zenoh.Config:
    """A Zenoh config for ``role`` on ``endpoint`` (``tcp/127.0.0.1:7447``).

    ``listen=True`` listens on the endpoint and connects nowhere; ``listen=False`` connects to
    it (waiting up to ``connect_timeout_s``) and listens nowhere; a connected client whose
    router goes away keeps retrying (every :data:`RECONNECT_INIT_MS` to
    :data:`RECONNECT_MAX_MS` ms) and Zenoh re-declares its subscriptions, publishers and
    liveliness tokens on the router it reaches again. Multicast scouting and gossip
    are off. ``lease_s`` sets ``transport/link/tx/lease`` (``None``: Zenoh's 10 s default).
    Raises :class:`BusError` for a malformed endpoint.
    """
    if not isinstance(endpoint, str) or not _ENDPOINT_RE.match(endpoint):
        raise BusError(f"bad Zenoh endpoint {endpoint!r}: expected e.g. tcp/127.0.0.1:7447")
    if role not in ("router", "client", "peer"):
        raise BusError(f"bad Zenoh role {role!r}: expected router, client or peer")
    if role == "client" and listen:
        raise BusError("a Zenoh client cannot listen; use role 'router' to listen on the endpoint")
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(role))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    if listen:
        c.insert_json5("listen/endpoints", json.dumps([endpoint]))
        c.insert_json5("connect/endpoints", "[]")
    else:
        c.insert_json5("listen/endpoints", "[]")
        c.insert_json5("connect/endpoints", json.dumps([endpoint]))
        c.insert_json5("connect/timeout_ms", str(max(1, int(connect_timeout_s * 1000))))
        c.insert_json5("connect/exit_on_failure", "true")  # at open; afterwards Zenoh retries
        retry = {
            "period_init_ms": RECONNECT_INIT_MS,
            "period_max_ms": RECONNECT_MAX_MS,
            "period_increase_factor": 2,
        }
        c.insert_json5("connect/retry", json.dumps(retry))
    if lease_s is not None:
        c.insert_json5("transport/link/tx/lease", str(max(100, int(lease_s * 1000))))
    return c


def open_session(
    endpoint: str,
    role: Role,
    *,
    listen: bool | None = None,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    lease_s: float | None = DEFAULT_LEASE_S,
) -> zenoh.Session:
    """Open a Zenoh session; the caller must ``close()`` it (``with open_session(...) as s``).

    ``listen`` defaults to ``role == "router"``. Raises :class:`BusError` with a message saying
    what to do: the port is in use, or no router answers at the endpoint within
    ``connect_timeout_s``.
    """
    do_listen = role == "router" if listen is None else listen
    config = zenoh_config(
        endpoint, role, listen=do_listen, connect_timeout_s=connect_timeout_s, lease_s=lease_s
    )
    try:
        return zenoh.open(config)
    except Exception as e:  # zenoh.ZError
        text = str(e)
        if "in use" in text.lower():
            raise BusError(
                f"cannot listen on {endpoint}: the address is in use (is another `fleet run` or "
                f"`fleet sim` running there?) — pass --endpoint with a free port, or attach to it "
                f"with `fleet status --endpoint {endpoint}`"
            ) from None
        if not do_listen and ("timeout" in text.lower() or "unable to connect" in text.lower()):
            raise BusError(
                f"no Zenoh router at {endpoint} — start `fleet run` (or `fleet sim`) first or pass --endpoint"
            ) from None
        raise BusError(f"cannot open a Zenoh {role} session on {endpoint}: {text}") from None


def has_router(session: zenoh.Session) -> bool:
    """Whether a client ``session`` is connected to a router now (its link to the bus)."""
    return any(True for _ in session.info.routers_zid())


class Declaration(Protocol):
    """A Zenoh declaration: a subscriber, a publisher or a liveliness token."""

    def undeclare(self) -> None: ...


class Closable(Protocol):
    """Something with ``close()``: a Zenoh session."""

    def close(self) -> None: ...


def undeclare_all(objs: Iterable[Declaration | None]) -> None:
    """Undeclare each of ``objs`` (``None`` skipped), best effort: a declaration whose session
    is already closed is ignored."""
    for obj in objs:
        if obj is None:
            continue
        try:
            obj.undeclare()
        except Exception as e:  # noqa: BLE001 - the session may already be closed
            logger.debug("undeclare %r: %s", obj, e)


def close_session(session: Closable) -> None:
    """Close a Zenoh session (typed wrapper: zenoh's stub leaves ``close`` unannotated)."""
    session.close()
