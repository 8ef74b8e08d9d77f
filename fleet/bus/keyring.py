"""The identities of a secured fleet bus (``fleet keys init``, ``--secure DIR``).

A key directory holds, each file mode 0600:

* ``<identity>.json5`` per identity: a complete Zenoh *client* config (mode ``client``, the
  router's endpoint, scouting off, ``transport.auth.usrpwd`` user and password) that a plain
  ``zenoh.open(zenoh.Config.from_file(path))`` can use as is. Identities: one per robot (named
  like the robot), ``coordinator``, ``simulator``, ``observer`` (read only) and ``worker``
  (a load test's agent worker);
* ``router.json5``: the config of the router session (``fleet run`` / ``fleet sim`` host it):
  listen endpoint, its own credentials, the password dictionary and the access control
  generated from :data:`fleet.bus.keys.ACCESS` (:mod:`fleet.bus.access`);
* ``router.passwords``: the router's ``user:password`` dictionary;
* ``api.token``: the bearer token of the task service's HTTP API for mutating calls.

Passwords and the token come from :mod:`secrets` (192 random bits each). With ``tls`` the
directory also holds ``tls/`` (:mod:`fleet.bus.certificates`: a CA, the router's certificate and
one client certificate per identity); the endpoint becomes ``tls/<host>:<port>`` and the router
requires mutual TLS. Without it credentials travel in the clear over TCP: keep the bus on
loopback or a trusted network (``docs/security.md``).
"""

from __future__ import annotations

import json
import logging
import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from fleet.bus.access import access_control
from fleet.bus.certificates import CA_FILE, TLS_DIR, endpoint_host, make_certificates, tls_endpoint, tls_paths
from fleet.bus.keys import RESERVED_CHUNKS, Role
from fleet.errors import BusError
from fleet.messages import check_robot_name

logger = logging.getLogger(__name__)

#: The identities made besides the robots, and their roles.
SERVICE_IDENTITIES: dict[str, Role] = {
    "coordinator": "coordinator",
    "simulator": "simulator",
    "observer": "observer",
    "worker": "worker",
}

#: The router's own user name.
ROUTER_USER = "router"
ROUTER_FILE = "router.json5"
PASSWORDS_FILE = "router.passwords"
API_TOKEN_FILE = "api.token"

#: Zenoh link lease (ms) written into every config (a frozen peer is gone after this long).
LEASE_MS = 1000

_SCOUTING_OFF = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}


def _secret() -> str:
    return secrets.token_urlsafe(24)


def _write_secret(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` readable by its owner only (mode 0600, also when it existed)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, text.encode())
    finally:
        os.close(fd)


def _json5(comment: str, body: dict[str, Any]) -> str:
    return f"// {comment}\n{json.dumps(body, indent=2)}\n"


def _client_tls(directory: Path, identity: str) -> dict[str, Any]:
    ca, cert, key = tls_paths(directory, identity)
    return {
        "root_ca_certificate": str(ca),
        "connect_certificate": str(cert),
        "connect_private_key": str(key),
        "enable_mtls": True,
    }


def _router_tls(directory: Path) -> dict[str, Any]:
    ca, cert, key = tls_paths(directory, ROUTER_USER)
    return {
        "root_ca_certificate": str(ca),
        "listen_certificate": str(cert),
        "listen_private_key": str(key),
        "enable_mtls": True,
    }


def client_config_dict(
    user: str, password: str, endpoint: str, tls_dir: Path | None = None
) -> dict[str, Any]:
    """The Zenoh client config of ``user`` connecting to the router at ``endpoint`` (with
    ``tls_dir``, the key directory: its TLS client certificate, mutual TLS)."""
    link: dict[str, Any] = {"tx": {"lease": LEASE_MS}}
    if tls_dir is not None:
        link["tls"] = _client_tls(tls_dir, user)
    return {
        "mode": "client",
        "connect": {"endpoints": [endpoint], "timeout_ms": 2000, "exit_on_failure": True},
        "listen": {"endpoints": []},
        "scouting": _SCOUTING_OFF,
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}}, "link": link},
    }


@dataclass(frozen=True)
class Keyring:
    """A key directory made by :func:`init_keyring` (see the module docstring)."""

    dir: Path

    def identity_file(self, identity: str) -> Path:
        return self.dir / f"{identity}.json5"

    @property
    def router_file(self) -> Path:
        return self.dir / ROUTER_FILE

    @property
    def tls(self) -> bool:
        """Whether the directory holds TLS material (``fleet keys init --tls``)."""
        return (self.dir / TLS_DIR / CA_FILE).is_file()

    def endpoint(self, endpoint: str) -> str:
        """``endpoint`` as this directory's sessions use it: ``tls/`` when it has TLS."""
        if not self.tls:
            return endpoint
        try:
            return tls_endpoint(endpoint)
        except ValueError as e:
            raise BusError(f"{self.dir}: {e}") from None

    @property
    def api_token_file(self) -> Path:
        return self.dir / API_TOKEN_FILE

    def _read(self, path: Path, what: str) -> str:
        try:
            if path.stat().st_mode & 0o077:
                logger.warning("%s is readable by others than its owner: chmod 600 %s", path, path)
            return path.read_text()
        except FileNotFoundError:
            raise BusError(
                f"no {what} {path} (make the key directory with `fleet keys init CONFIG {self.dir}`)"
            ) from None
        except OSError as e:
            raise BusError(f"cannot read {what} {path}: {e.strerror}") from None

    def api_token(self) -> str:
        """The API's bearer token (:class:`BusError` naming the file if it is missing or empty)."""
        token = self._read(self.api_token_file, "API token").strip()
        if not token:
            raise BusError(f"the API token file {self.api_token_file} is empty")
        return token

    def _config(self, path: Path, what: str) -> zenoh.Config:
        self._read(path, what)
        try:
            return zenoh.Config.from_file(str(path))
        except Exception as e:  # zenoh.ZError: not JSON5, or not a Zenoh config
            raise BusError(f"{path} is not a valid Zenoh config: {e}") from None

    def client_config(self, identity: str, endpoint: str | None = None) -> zenoh.Config:
        """The Zenoh config of ``identity`` (its file as is; ``endpoint`` replaces the router
        endpoint written in it)."""
        c = self._config(self.identity_file(identity), f"identity file for {identity!r}")
        if endpoint is not None:
            c.insert_json5("connect/endpoints", json.dumps([self.endpoint(endpoint)]))
        if self.tls:  # the files next to this one, wherever the directory moved
            c.insert_json5("transport/link/tls", json.dumps(_client_tls(self.dir, identity)))
        return c

    def written_endpoint(self) -> str | None:
        """The endpoint ``fleet keys init`` wrote into the router config (what the identity
        files connect to when a plain Zenoh session opens them), or None if unreadable."""
        try:
            listen: list[str] = json.loads(
                self._config(self.router_file, "router config").get_json("listen/endpoints")
            )
        except (BusError, ValueError):
            return None
        return listen[0] if listen else None

    def access(self) -> dict[str, Any]:
        """The router config's ``access_control`` section (what the router enforces)."""
        acl: dict[str, Any] = json.loads(self.router_config().get_json("access_control"))
        return acl

    def router_config(self, endpoint: str | None = None) -> zenoh.Config:
        """The router session's config (``endpoint`` replaces the listen endpoint; the
        password dictionary is the one next to the file, wherever the directory moved)."""
        c = self._config(self.router_file, "router config")
        self._read(self.dir / PASSWORDS_FILE, "password dictionary")
        c.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(self.dir / PASSWORDS_FILE)))
        if endpoint is not None:
            c.insert_json5("listen/endpoints", json.dumps([self.endpoint(endpoint)]))
        if self.tls:
            c.insert_json5("transport/link/tls", json.dumps(_router_tls(self.dir)))
        return c


def check_identity_names(robots: list[str]) -> None:
    """ValueError naming the robot if a robot name cannot be an identity (not a key chunk,
    a fleet keyword, or the name of another identity) or appears twice."""
    taken = {*SERVICE_IDENTITIES, ROUTER_USER, *RESERVED_CHUNKS, "api"}
    seen: set[str] = set()
    for r in robots:
        check_robot_name(r)
        if r in taken:
            raise ValueError(f"robot name {r!r} is reserved (identities {', '.join(sorted(taken))})")
        if r in seen:
            raise ValueError(f"robot name {r!r} appears twice")
        seen.add(r)


def keyring_files(robots: list[str], tls: bool = False) -> list[str]:
    """The file names (relative to the directory) :func:`init_keyring` writes for ``robots``."""
    names = [*robots, *SERVICE_IDENTITIES]
    files = [*(f"{n}.json5" for n in names), ROUTER_FILE, PASSWORDS_FILE, API_TOKEN_FILE]
    if tls:
        files += [
            f"{TLS_DIR}/{CA_FILE}",
            *(f"{TLS_DIR}/{n}.{ext}" for n in [ROUTER_USER, *names] for ext in ("pem", "key")),
        ]
    return files


def _write_tls(ring: Keyring, endpoint: str, identities: list[str]) -> None:
    ca, certs = make_certificates(endpoint_host(endpoint), identities)
    (ring.dir / TLS_DIR).mkdir(mode=0o700, exist_ok=True)
    _write_secret(ring.dir / TLS_DIR / CA_FILE, ca.decode())
    for name, pem in certs.items():
        _, cert, key = tls_paths(ring.dir, name)
        _write_secret(cert, pem.cert.decode())
        _write_secret(key, pem.key.decode())


# long: one file after the other, each a few lines, so what the directory holds reads in one place
def init_keyring(
    directory: Path, robots: list[str], endpoint: str, *, force: bool = False, tls: bool = False
) -> Keyring:
    """Make the key directory ``directory`` for ``robots`` on ``endpoint`` (created mode 0700
    if missing; ``tls``: with TLS material, the endpoint becoming ``tls/``). Refuses
    (:class:`BusError` naming the file) to overwrite an existing file unless ``force``;
    ValueError for a robot name that cannot be an identity or an endpoint TLS cannot use."""
    check_identity_names(robots)
    if tls:
        endpoint = tls_endpoint(endpoint)
    if directory.exists() and not directory.is_dir():
        raise BusError(f"{directory} exists and is not a directory")
    if not force:
        for name in keyring_files(robots, tls):
            if (directory / name).exists():
                raise BusError(f"{directory / name} exists; pass --force to replace every key in {directory}")
    try:
        directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as e:
        raise BusError(f"cannot make the key directory {directory}: {e.strerror}") from None
    ring = Keyring(directory.resolve())
    roles: dict[str, tuple[Role, str | None]] = {r: ("robot", r) for r in robots}
    roles.update({name: (role, None) for name, role in SERVICE_IDENTITIES.items()})
    passwords = {name: _secret() for name in [ROUTER_USER, *roles]}
    if tls:
        _write_tls(ring, endpoint, list(roles))
    elif (ring.dir / TLS_DIR).exists():  # --force without --tls: no stale certificates
        for f in (ring.dir / TLS_DIR).iterdir():
            f.unlink()
        (ring.dir / TLS_DIR).rmdir()
    for name, (role, _) in roles.items():
        body = client_config_dict(name, passwords[name], endpoint, ring.dir if tls else None)
        _write_secret(
            ring.identity_file(name), _json5(f"fleet bus identity {name!r} ({role}); keep it secret", body)
        )
    router = {
        "mode": "router",
        "listen": {"endpoints": [endpoint]},
        "connect": {"endpoints": []},
        "scouting": _SCOUTING_OFF,
        "transport": {
            "auth": {
                "usrpwd": {
                    "user": ROUTER_USER,
                    "password": passwords[ROUTER_USER],
                    "dictionary_file": str(ring.dir / PASSWORDS_FILE),
                }
            },
            "link": {"tx": {"lease": LEASE_MS}, **({"tls": _router_tls(ring.dir)} if tls else {})},
        },
        "access_control": access_control(roles, certificates=tls),
    }
    _write_secret(
        ring.router_file, _json5("the fleet's Zenoh router: credentials and access control", router)
    )
    _write_secret(ring.dir / PASSWORDS_FILE, "".join(f"{u}:{p}\n" for u, p in passwords.items()))
    _write_secret(ring.api_token_file, _secret() + "\n")
    return ring
