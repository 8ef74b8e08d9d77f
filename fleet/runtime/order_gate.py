"""Which orders and grants from the bus an agent applies (``docs/protocol.md``).

An order (:class:`~fleet.messages.TaskMessage`) or a grant (:class:`~fleet.messages.Grant`)
from the bus is applied only if

* a coordinator lease is live and the message carries its ``epoch`` (a message from a dead
  coordinator, from a second one that was refused, or forged with a made-up epoch is ignored);
* its ``seq`` is newer than the last one applied under that lease, and at most
  :data:`MAX_SEQ_GAP` ahead of it (a forged jump such as 2^53 cannot lock the robot out of the
  real coordinator's next orders; a jump within the gap is healed: the agent acknowledges the
  sequence it applied in its status and the coordinator continues above it).

A copy of the last applied message (same ``seq``) is a duplicate: ignored, counted apart.
Everything else is *rejected*: counted by reason (:attr:`OrderGate.rejected`) and ignored.
A new lease (another coordinator took over) starts its sequences afresh; the same lease seen
again (a reconnect) keeps them. Thread-safe.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal

from fleet.messages import Grant, TaskMessage

if TYPE_CHECKING:
    from fleet.bus.lease import Lease

#: A sequence number more than this far ahead of the last one applied is rejected.
MAX_SEQ_GAP = 10_000
#: Sequences are remembered for this many leases (older ones are forgotten first).
_LEASES_KEPT = 8

Kind = Literal["task", "grant"]


class OrderGate:
    """Admission of one robot's orders and grants. ``lease()`` returns the live coordinator
    lease (:meth:`fleet.bus.lease.LeaseWatch.current`)."""

    def __init__(self, lease: Callable[[], Lease | None]) -> None:
        self._lease = lease
        self._lock = threading.Lock()
        self._seqs: dict[Lease, dict[Kind, int]] = {}
        #: Ignored messages by reason (``no live coordinator``, ``wrong epoch``, ``stale seq``,
        #: ``seq jump``).
        self.rejected: dict[str, int] = {}
        self.last_rejected: str | None = None
        #: Copies of the last applied message (resends), ignored.
        self.duplicates = 0

    @property
    def rejected_total(self) -> int:
        with self._lock:
            return sum(self.rejected.values())

    def admit(self, kind: Kind, msg: TaskMessage | Grant) -> bool:
        """Whether to apply ``msg`` (``kind`` ``task`` or ``grant``); if so, its ``seq``
        becomes the last applied."""
        lease = self._lease()
        with self._lock:
            if lease is None:
                return self._reject("no live coordinator", kind, msg)
            if msg.epoch != lease.epoch:
                return self._reject("wrong epoch", kind, msg, f" (live: {lease.epoch})")
            seqs = self._seqs.get(lease)
            if seqs is None:
                seqs = self._seqs[lease] = {"task": 0, "grant": 0}
                while len(self._seqs) > _LEASES_KEPT:
                    self._seqs.pop(next(iter(self._seqs)))
            last = seqs[kind]
            if msg.seq == last:
                self.duplicates += 1
                return False
            if msg.seq < last:
                return self._reject("stale seq", kind, msg, f" (last applied {last})")
            if msg.seq > last + MAX_SEQ_GAP:
                return self._reject("seq jump", kind, msg, f" (last applied {last})")
            seqs[kind] = msg.seq
            return True

    def _reject(self, reason: str, kind: Kind, msg: TaskMessage | Grant, detail: str = "") -> bool:
        # caller holds self._lock
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        self.last_rejected = f"{kind} epoch {msg.epoch} seq {msg.seq}: {reason}{detail}"
        return False
