"""The identities of a secured fleet bus (``fleet keys init``, ``--secure DIR``).

A key directory holds, each file mode 0600:

* ``<identity>.json5`` per identity: a complete Zenoh *client* config (mode ``client``, the
  router's endpoint, scouting off, ``transport.auth.usrpwd`` user and password) that a plain
  ``zenoh.open(zenoh.Config.from_file(path))`` can use as is. Identities: one per robot (named
  like the robot), ``coordinator``, ``simulator`` and ``observer`` (read only);
* ``router.json5``: the config of the router session (``fleet run`` / ``fleet sim`` host it):
  listen endpoint, its own credentials, the password dictionary and the access control
  generated from :data:`fleet.bus.keys.ACCESS` (:mod:`fleet.bus.access`);
* ``router.passwords``: the router's ``user:password`` dictionary;
* ``api.token``: the bearer token of the task service's HTTP API for mutating calls.

Passwords and the token come from :mod:`secrets` (192 random bits each). TLS is not part of
this directory: credentials travel in the clear over TCP, so keep the bus on loopback or a
trusted network (``docs/security.md``).
"""

from __future__ import annotations

import json
import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from fleet.bus.access import access_control
from fleet.bus.keys import RESERVED_CHUNKS, Role
from fleet.errors import BusError
from fleet.messages import check_robot_name

#: The identities made besides the robots, and their roles.
SERVICE_IDENTITIES: dict[str, Role] = {
    "coordinator": "coordinator",
    "simulator": "simulator",
    "observer": "observer",
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


def client_config_dict(user: str, password: str, endpoint: str) -> dict[str, Any]:
    """The Zenoh client config of ``user`` connecting to the router at ``endpoint``."""
    return {
        "mode": "client",
        "connect": {"endpoints": [endpoint], "timeout_ms": 2000, "exit_on_failure": True},
        "listen": {"endpoints": []},
        "scouting": _SCOUTING_OFF,
        "transport": {
            "auth": {"usrpwd": {"user": user, "password": password}},
            "link": {"tx": {"lease": LEASE_MS}},
        },
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
    def api_token_file(self) -> Path:
        return self.dir / API_TOKEN_FILE

    def _read(self, path: Path, what: str) -> str:
        try:
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
            c.insert_json5("connect/endpoints", json.dumps([endpoint]))
        return c

    def router_config(self, endpoint: str | None = None) -> zenoh.Config:
        """The router session's config (``endpoint`` replaces the listen endpoint; the
        password dictionary is the one next to the file, wherever the directory moved)."""
        c = self._config(self.router_file, "router config")
        self._read(self.dir / PASSWORDS_FILE, "password dictionary")
        c.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(self.dir / PASSWORDS_FILE)))
        if endpoint is not None:
            c.insert_json5("listen/endpoints", json.dumps([endpoint]))
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


def keyring_files(robots: list[str]) -> list[str]:
    """The file names :func:`init_keyring` writes for ``robots``."""
    names = [*robots, *SERVICE_IDENTITIES]
    return [*(f"{n}.json5" for n in names), ROUTER_FILE, PASSWORDS_FILE, API_TOKEN_FILE]


def init_keyring(directory: Path, robots: list[str], endpoint: str, *, force: bool = False) -> Keyring:
    """Make the key directory ``directory`` for ``robots`` on ``endpoint`` (created mode 0700
    if missing). Refuses (:class:`BusError` naming the file) to overwrite an existing file
    unless ``force``; ValueError for a robot name that cannot be an identity."""
    check_identity_names(robots)
    if directory.exists() and not directory.is_dir():
        raise BusError(f"{directory} exists and is not a directory")
    if not force:
        for name in keyring_files(robots):
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
    for name, (role, _) in roles.items():
        body = client_config_dict(name, passwords[name], endpoint)
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
            "link": {"tx": {"lease": LEASE_MS}},
        },
        "access_control": access_control(roles),
    }
    _write_secret(
        ring.router_file, _json5("the fleet's Zenoh router: credentials and access control", router)
    )
    _write_secret(ring.dir / PASSWORDS_FILE, "".join(f"{u}:{p}\n" for u, p in passwords.items()))
    _write_secret(ring.api_token_file, _secret() + "\n")
    return ring
