"""Opening Zenoh sessions for the fleet: explicit endpoints, scouting off, a short lease.

One process *listens* on the endpoint in ``router`` mode (``fleet run``, ``fleet sim``); every
other process connects in ``client`` mode (a ``peer`` that does not listen receives nothing
through a router)."""

from __future__ import annotations

import json
import logging
import re
import socket
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

import zenoh

from fleet.errors import BusError

if TYPE_CHECKING:
    from fleet.bus.keyring import Keyring

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


@dataclass(frozen=True)
class Secure:
    """Open sessions on a secured bus (``--secure DIR``): ``keys`` is the key directory made
    by ``fleet keys init``; ``identity`` the identity a client session uses (a robot's name,
    ``coordinator``, ``simulator`` or ``observer``). A router session uses the directory's
    router config whatever ``identity`` says."""

    keys: Path
    identity: str

    def keyring(self) -> Keyring:
        from fleet.bus.keyring import Keyring

        return Keyring(self.keys)

    def with_identity(self, identity: str) -> Secure:
        return Secure(self.keys, identity)


def checked_secure(keys: Path, identity: str = "worker") -> Secure:
    """``Secure(keys, identity)`` once checked: :class:`BusError` naming the path if ``keys`` is
    not a key directory holding that identity (``"router"``: the router's config)."""
    from fleet.bus.keyring import Keyring

    ring = Keyring(keys)
    if not keys.is_dir():
        raise BusError(
            f"--secure {keys}: no such key directory (make it with `fleet keys init CONFIG {keys}`)"
        )
    for path, what in (
        (ring.router_file, "a key directory"),
        (ring.identity_file(identity), f"identity {identity!r}"),
    ):
        if not path.is_file():
            older = (
                "; one made before load-test workers existed needs `--force`" if identity == "worker" else ""
            )
            raise BusError(
                f"--secure {keys}: not {what}: {path} is missing (make the keys with `fleet keys init CONFIG "
                f"{keys}`{older})"
            )
    return Secure(keys, identity)


def bus_note(secure: Secure | None) -> str:
    """How a command describes its bus in its first line: open, or secured as whom."""
    if secure is None:
        return "open bus: unauthenticated, anyone reaching the endpoint may command robots (--secure DIR locks it)"
    over = "over TLS (tls/ endpoint), " if secure.keyring().tls else ""
    return f"secured bus: {over}identity {secure.identity!r} from {secure.keys}"


_warned_endpoints: set[tuple[Path, str]] = set()


def _warn_other_endpoint(ring: Keyring, endpoint: str) -> None:
    """Warn once per directory and endpoint when a session runs on another endpoint than the
    one its key directory was made for: the fleet's commands use their own (``--endpoint``
    or the config's ``bus.endpoint``), but a plain Zenoh session opening the directory's
    identity files connects to the written one and would find no router."""
    written = ring.written_endpoint()
    if written is None or written == endpoint or (ring.dir, endpoint) in _warned_endpoints:
        return
    _warned_endpoints.add((ring.dir, endpoint))
    logger.warning(
        "the keys in %s were made for %s but this fleet's bus is %s (--endpoint or the config's "
        "bus.endpoint); the fleet's own commands follow the bus, but plain Zenoh sessions opening "
        "the identity files connect to %s: remake them with `fleet keys init CONFIG %s --endpoint %s --force`",
        ring.dir,
        written,
        endpoint,
        written,
        ring.dir,
        endpoint,
    )


def _secure_config(
    secure: Secure, endpoint: str, role: Role, do_listen: bool, connect_timeout_s: float
) -> zenoh.Config:
    if not isinstance(endpoint, str) or not _ENDPOINT_RE.match(endpoint):
        raise BusError(f"bad Zenoh endpoint {endpoint!r}: expected e.g. tcp/127.0.0.1:7447")
    ring = secure.keyring()
    _warn_other_endpoint(ring, ring.endpoint(endpoint))
    if role == "router":
        return ring.router_config(endpoint)
    if do_listen:
        raise BusError("on a secured bus only the router listens; connect as a client")
    c = ring.client_config(secure.identity, endpoint)
    c.insert_json5("connect/timeout_ms", str(max(1, int(connect_timeout_s * 1000))))
    return c


def open_session(
    endpoint: str,
    role: Role,
    *,
    listen: bool | None = None,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    lease_s: float | None = DEFAULT_LEASE_S,
    secure: Secure | None = None,
) -> zenoh.Session:
    """Open a Zenoh session; the caller must ``close()`` it (``with open_session(...) as s``).

    ``listen`` defaults to ``role == "router"``. With ``secure`` a router session enforces the
    key directory's credentials and access control, and a client session authenticates as
    ``secure.identity`` (its ``lease_s`` is the identity file's). Raises :class:`BusError` with
    a message saying what to do: the port is in use, no router answers at the endpoint within
    ``connect_timeout_s`` (or it refused the identity), a key file is missing.
    """
    do_listen = role == "router" if listen is None else listen
    if secure is not None:
        config = _secure_config(secure, endpoint, role, do_listen, connect_timeout_s)
    else:
        config = zenoh_config(
            endpoint, role, listen=do_listen, connect_timeout_s=connect_timeout_s, lease_s=lease_s
        )
    try:
        return zenoh.open(config)
    except Exception as e:  # zenoh.ZError
        text = str(e)
        unreachable = "timeout" in text.lower() or "unable to connect" in text.lower()
        if secure is not None and not do_listen and unreachable:
            raise BusError(
                f"cannot connect to the secured router at {secure.keyring().endpoint(endpoint)} as identity {secure.identity!r} "
                f"({secure.keyring().identity_file(secure.identity)}): the router refused these "
                f"credentials or is not running there (keys from another `fleet keys init`?)"
            ) from None
        if "in use" in text.lower():
            raise BusError(
                f"cannot listen on {endpoint}: the address is in use (is another `fleet run` or "
                f"`fleet sim` running there?) — pass --endpoint with a free port, or attach to it "
                f"with `fleet status --endpoint {endpoint}`"
            ) from None
        if not do_listen and unreachable:
            raise BusError(
                f"no Zenoh router at {endpoint} — start `fleet run` (or `fleet sim`) first or pass --endpoint"
            ) from None
        raise BusError(f"cannot open a Zenoh {role} session on {endpoint}: {text}") from None


def free_endpoint() -> str:
    """``tcp/127.0.0.1:<port>`` on a port that is free now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


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
