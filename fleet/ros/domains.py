"""Private ROS domains for tests and benchmarks: claimed, so two runs never share one.

A ROS domain is the unit of DDS discovery: two processes on the same domain id see (and
match) each other's endpoints. Tests and benchmarks that run side by side on one machine
(pytest workers, another engineer's run, a CI run) must each have domains nobody else uses.
Deriving an id from the process id alone is not enough: pytest workers have consecutive pids,
so ``base + pid % span`` of one worker *plus one* (a second domain for a shard) is the next
worker's domain.

:func:`claim_domains` takes ``count`` consecutive ids and holds an exclusive ``flock`` on one
file per id under :data:`LOCK_DIR` (``$TMPDIR/fleet-ros-domains``). The search starts at an
offset derived from the pid (so concurrent claimers rarely probe the same ids) and goes round
the range. The locks belong to the open files: they are released by :meth:`DomainClaim.release`,
by leaving the ``with`` block, or by the kernel when the process ends however it ends (a
``kill -9`` leaves no stale claim). Only claimers see claims: a process that sets
``ROS_DOMAIN_ID`` by hand is not protected, which is why every test and benchmark of the
project claims through here.

Imports nothing from ROS.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import MutableMapping
from pathlib import Path
from typing import IO

from fleet.errors import BackendError

#: Directory of the lock files (one ``domain-<id>.lock`` per claimed id).
LOCK_DIR = Path(tempfile.gettempdir()) / "fleet-ros-domains"
#: Highest ROS domain id (ROS 2; FastDDS's ports stay below 65536 up to it).
MAX_DOMAIN_ID = 232

#: Claims made by :func:`private_domain_id`, held for the life of this process.
_PROCESS_CLAIMS: list[DomainClaim] = []


class DomainClaim:
    """``count`` consecutive ROS domain ids held by this process: ``ids``, first ``first``.
    A context manager; :meth:`release` (idempotent) frees them for other claimers."""

    def __init__(self, first: int, files: list[IO[bytes]]) -> None:
        #: The first claimed id.
        self.first = first
        #: Every claimed id, ascending and consecutive.
        self.ids = list(range(first, first + len(files)))
        self._files = files

    def release(self) -> None:
        """Free the ids (closing the lock files drops the locks)."""
        for f in self._files:
            f.close()
        self._files = []

    def __enter__(self) -> DomainClaim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"DomainClaim(ids={self.ids})"


def _try_lock(domain_id: int) -> IO[bytes] | None:
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    f = open(LOCK_DIR / f"domain-{domain_id}.lock", "ab")  # noqa: SIM115 - held by the claim
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.close()
        return None
    return f


def claim_domains(count: int = 1, *, base: int = 40, span: int = 150, align: int = 1) -> DomainClaim:
    """Claim ``count`` consecutive free ROS domain ids in ``[base, base + span)``, the first a
    multiple of ``align`` (e.g. ``align=2`` for a pair ``d, d ^ 1``).

    Raises :class:`~fleet.errors.BackendError` when the range is invalid or every candidate
    block has an id claimed by another process."""
    if count < 1 or align < 1 or base < 0 or base + span - 1 > MAX_DOMAIN_ID:
        raise BackendError(
            f"cannot claim {count} ROS domains in [{base}, {base + span}) aligned to {align}: "
            f"ids must lie in 0..{MAX_DOMAIN_ID}"
        )
    starts = [d for d in range(base, base + span - count + 1) if d % align == 0]
    if not starts:
        raise BackendError(f"no block of {count} ROS domains fits in [{base}, {base + span})")
    offset = os.getpid() % len(starts)
    for first in starts[offset:] + starts[:offset]:
        files: list[IO[bytes]] = []
        for d in range(first, first + count):
            f = _try_lock(d)
            if f is None:
                break
            files.append(f)
        if len(files) == count:
            return DomainClaim(first, files)
        for f in files:
            f.close()
    raise BackendError(
        f"every block of {count} ROS domains in [{base}, {base + span}) is claimed by another "
        f"process (locks in {LOCK_DIR})"
    )


def private_domain_id(base: int = 40, span: int = 150) -> int:
    """A ROS domain id in ``[base, base + span)`` claimed for the rest of this process's life
    (:func:`claim_domains`; tests and benchmarks put it in ``ROS_DOMAIN_ID``)."""
    claim = claim_domains(1, base=base, span=span)
    _PROCESS_CLAIMS.append(claim)
    return claim.first


#: Set beside ``ROS_DOMAIN_ID`` by :func:`ensure_private_domain`: the pid of the process that
#: claimed it (children inherit both; a claim dies with its process).
CLAIMED_BY_ENV = "FLEET_ROS_DOMAIN_CLAIMED_BY"


def ensure_private_domain(environ: MutableMapping[str, str] = os.environ) -> int:
    """``ROS_DOMAIN_ID`` of this process, claimed here unless set by hand.

    A domain the user set (no :data:`CLAIMED_BY_ENV` beside it) is kept. A domain this
    process claimed is kept. A domain claimed by *another* process and inherited from it (a
    pytest-xdist controller that loaded a test conftest before starting its workers) is not
    this process's: it claims its own, so two workers never share one."""
    owner = environ.get(CLAIMED_BY_ENV)
    if "ROS_DOMAIN_ID" in environ and (owner is None or owner == str(os.getpid())):
        return int(environ["ROS_DOMAIN_ID"])
    domain_id = private_domain_id()
    environ["ROS_DOMAIN_ID"] = str(domain_id)
    environ[CLAIMED_BY_ENV] = str(os.getpid())
    return domain_id
