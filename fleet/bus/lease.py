"""Exclusive leases on the bus: one coordinator per fleet, one agent per robot.

A lease is a Zenoh liveliness token: it exists while its holder's session is open and
disappears when the process ends (a killed process's token goes within milliseconds, a frozen
one after the session's link lease). Protocol: ``docs/protocol.md``.

* The coordinator's lease is ``fleet/coordinator/lease/<epoch>/<owner>``: ``epoch`` grows each
  time a coordinator takes over (:func:`next_epoch`), ``owner`` is its Zenoh session id. Orders
  and grants carry the epoch; agents apply only those whose epoch is the live lease's
  (:class:`LeaseWatch` tells them which one that is), so an order that no live coordinator
  could have sent is ignored.
* A robot's lease is its liveliness token ``fleet/<robot>/alive`` (held by its agent).

:func:`acquire_coordinator_lease` and :func:`claim_robots` look for a live holder first and
refuse with :class:`~fleet.errors.LeaseError` (the CLI's exit code 2) naming it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from typing import NamedTuple

import zenoh

from fleet.bus.keys import LEASE_KEYS, SIM_LEASE_KEYS, agent_claim_key, alive_key
from fleet.bus.session import Declaration, undeclare_all
from fleet.errors import LeaseError

_PREFIX = "fleet/coordinator/lease/"
#: How long a liveliness query for existing holders may take (wall seconds).
QUERY_TIMEOUT_S = 2.0


class Lease(NamedTuple):
    """A coordinator lease: its ``epoch`` and ``owner`` (the holder's Zenoh session id).
    Leases order by epoch, then owner."""

    epoch: int
    owner: str


def lease_key(lease: Lease) -> str:
    """``fleet/coordinator/lease/<epoch>/<owner>``."""
    return f"{_PREFIX}{lease.epoch}/{lease.owner}"


def parse_lease_key(key: str) -> Lease | None:
    """The lease named by a token key, or ``None`` if the key is not a lease's."""
    if not key.startswith(_PREFIX):
        return None
    parts = key[len(_PREFIX) :].split("/")
    if len(parts) != 2 or not parts[0].isdigit() or not parts[1] or len(parts[0]) > 16:
        return None
    return Lease(int(parts[0]), parts[1])


def next_epoch(previous: int, now_s: float | None = None) -> int:
    """The epoch of a coordinator taking over after ``previous`` (from its durable task book,
    ``0`` without one): above ``previous`` and at least the wall time in milliseconds, so
    epochs also grow across coordinators that keep no book."""
    wall_ms = int((time.time() if now_s is None else now_s) * 1000)
    return max(int(previous) + 1, wall_ms)


def live_leases(session: zenoh.Session, timeout_s: float = QUERY_TIMEOUT_S) -> list[Lease]:
    """The coordinator leases held now (a liveliness query), highest first."""
    found: set[Lease] = set()
    for reply in session.liveliness().get(LEASE_KEYS, timeout=timeout_s):
        ok = reply.ok
        if ok is not None:
            lease = parse_lease_key(str(ok.key_expr))
            if lease is not None:
                found.add(lease)
    return sorted(found, reverse=True)


class CoordinatorLease:
    """The coordinator lease this process holds (:func:`acquire_coordinator_lease`);
    :meth:`release` drops it (idempotent; closing the session drops it too)."""

    def __init__(self, lease: Lease, token: Declaration) -> None:
        self.lease = lease
        self._token: Declaration | None = token

    @property
    def epoch(self) -> int:
        return self.lease.epoch

    def release(self) -> None:
        token, self._token = self._token, None
        undeclare_all([token])


def acquire_coordinator_lease(session: zenoh.Session, epoch: int, endpoint: str) -> CoordinatorLease:
    """Hold the coordinator lease of ``epoch`` on ``session``.

    Raises :class:`~fleet.errors.LeaseError` if another coordinator's lease is live (checked
    before declaring ours, and again after, so of two coordinators starting at once the one
    with the lower lease steps back)."""
    held = live_leases(session)
    if held:
        raise LeaseError(_another(held[0], endpoint))
    lease = Lease(int(epoch), str(session.zid()))
    token: Declaration = session.liveliness().declare_token(lease_key(lease))
    others = [x for x in live_leases(session) if x != lease]
    if others and others[0] > lease:
        undeclare_all([token])
        raise LeaseError(_another(others[0], endpoint))
    return CoordinatorLease(lease, token)


def _another(held: Lease, endpoint: str) -> str:
    return (
        f"another coordinator is live on {endpoint} (epoch {held.epoch}, session {held.owner}): "
        "only one coordinator may command a fleet; stop it first"
    )


#: A process with at most this many agents also holds a claim token per robot while it runs
#: (the split deployment's ``fleet agent``, where two starts at once are a real risk); a fleet
#: run with more agents checks the liveliness tokens only (a token per robot costs declarations).
CLAIM_TOKENS_MAX = 64


def claim_robots(session: zenoh.Session, robots: Iterable[str], endpoint: str) -> list[Declaration]:
    """Refuse (:class:`~fleet.errors.LeaseError`) if any of ``robots`` already has a live agent
    (its token ``fleet/<robot>/alive`` is held); call before this process's agents declare
    theirs.

    With at most :data:`CLAIM_TOKENS_MAX` robots it then declares a claim token per robot
    (``fleet/<robot>/agent/<session id>``) and looks again: if another process claims one of
    them, both started at once, and this one steps back (so does the other when it sees this
    claim: a tie refuses both rather than letting two agents drive one robot). The caller keeps
    the returned tokens for as long as its agents run (closing the session drops them)."""
    wanted = {alive_key(r): r for r in robots}
    if not wanted:
        return []
    live: set[str] = set()
    for reply in session.liveliness().get("fleet/*/alive", timeout=QUERY_TIMEOUT_S):
        ok = reply.ok
        if ok is not None and str(ok.key_expr) in wanted:
            live.add(wanted[str(ok.key_expr)])
    if live:
        names = ", ".join(sorted(live))
        tokens = ", ".join(alive_key(r) for r in sorted(live))
        raise LeaseError(
            f"robot {names} already has a live agent on {endpoint} (token {tokens} is held): "
            "only one agent may drive a robot; stop the other one first"
        )
    if len(wanted) > CLAIM_TOKENS_MAX:
        return []
    return _claim_tokens(session, sorted(wanted.values()), endpoint)


def _claim_tokens(session: zenoh.Session, robots: list[str], endpoint: str) -> list[Declaration]:
    me = str(session.zid())
    tokens: list[Declaration] = [session.liveliness().declare_token(agent_claim_key(r, me)) for r in robots]
    for robot in robots:
        for reply in session.liveliness().get(agent_claim_key(robot), timeout=QUERY_TIMEOUT_S):
            ok = reply.ok
            if ok is not None and str(ok.key_expr) != agent_claim_key(robot, me):
                undeclare_all(tokens)
                raise LeaseError(
                    f"robot {robot}: another agent is starting on {endpoint} at the same moment "
                    f"(token {ok.key_expr}): only one agent may drive a robot; start one of them again"
                )
    return tokens


def sim_lease_key(owner: str) -> str:
    """``fleet/sim/lease/<owner>``: the token of the simulator whose session id is ``owner``."""
    return f"fleet/sim/lease/{owner}"


class SimLeaseWatch:
    """Which simulators are live (the tokens ``fleet/sim/lease/*``, history included):
    :meth:`admits` tells whether a navigation state or clock message's ``src`` is one of them.
    Call :meth:`close` when done (the session stays open)."""

    def __init__(self, session: zenoh.Session) -> None:
        self._lock = threading.Lock()
        self._live: set[str] = set()
        self._sub: Declaration | None = session.liveliness().declare_subscriber(
            SIM_LEASE_KEYS, self._on_sample, history=True
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        owner = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._live.add(owner)
            else:
                self._live.discard(owner)

    def admits(self, src: str) -> bool:
        with self._lock:
            return src in self._live

    def close(self) -> None:
        sub, self._sub = self._sub, None
        undeclare_all([sub])


class LeaseWatch:
    """Which coordinator lease is live, from the liveliness tokens ``fleet/coordinator/lease/**``
    (history included). :meth:`current` is the highest live lease, or ``None`` while no
    coordinator is live. ``on_change(lease)`` (optional) runs on Zenoh's thread when it changes.
    Call :meth:`close` when done (the session stays open)."""

    def __init__(
        self, session: zenoh.Session, on_change: Callable[[Lease | None], None] | None = None
    ) -> None:
        self._lock = threading.Lock()
        self._live: set[Lease] = set()
        self._current: Lease | None = None
        self.on_change = on_change
        #: Lease tokens seen appear (``changes`` counts changes of :meth:`current`).
        self.changes = 0
        self._sub: Declaration | None = session.liveliness().declare_subscriber(
            LEASE_KEYS, self._on_sample, history=True
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        lease = parse_lease_key(str(sample.key_expr))
        if lease is None:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._live.add(lease)
            else:
                self._live.discard(lease)
            new = max(self._live) if self._live else None
            changed = new != self._current
            self._current = new
            if changed:
                self.changes += 1
        if changed and self.on_change is not None:
            try:
                self.on_change(new)
            except Exception:  # noqa: BLE001 - never raise into Zenoh's thread
                pass

    def current(self) -> Lease | None:
        with self._lock:
            return self._current

    def close(self) -> None:
        sub, self._sub = self._sub, None
        undeclare_all([sub])
