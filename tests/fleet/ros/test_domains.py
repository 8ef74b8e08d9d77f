"""Claimed ROS domains (:mod:`fleet.ros.domains`): two claimers on one machine never get the
same id, a dead claimer's ids come free, and a full range is a clear error.

Real ``flock`` locks held by real processes (this one and a child), in a private lock
directory so the test meets no other run's claims. Needs no ROS.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from fleet.errors import BackendError
from fleet.ros import domains
from fleet.ros.domains import claim_domains

#: Hang guard (wall s) for the child claimer to report its claim.
CHILD_S = 60.0


@pytest.fixture(autouse=True)
def lock_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setattr(domains, "LOCK_DIR", tmp_path)
    return tmp_path


def _child_claim(
    lock_dir: Path, count: int, base: int, span: int, align: int = 1
) -> tuple[subprocess.Popen[str], list[int]]:
    """A child process that claims ``count`` domains in ``[base, base + span)`` and holds them
    until killed; returns it and its ids."""
    code = (
        "import sys\nfrom pathlib import Path\nfrom fleet.ros import domains\n"
        f"domains.LOCK_DIR = Path({str(lock_dir)!r})\n"
        f"c = domains.claim_domains({count}, base={base}, span={span}, align={align})\n"
        "print(*c.ids, flush=True)\nsys.stdin.read()\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()  # bounded: the child prints at once or exits (EOF)
    assert line, f"the child claimer failed (exit {proc.wait(timeout=CHILD_S)})"
    return proc, [int(x) for x in line.split()]


def test_claims_of_two_processes_never_overlap(lock_dir: Path) -> None:
    """A child holds a pair of 4 ids; this process's claim of a pair gets the other two; a
    third claim finds none free and says so, naming the lock directory."""
    child, theirs = _child_claim(lock_dir, 2, base=100, span=4, align=2)
    try:
        with claim_domains(2, base=100, span=4, align=2) as mine:
            assert len(mine.ids) == 2 and mine.ids[1] == mine.ids[0] + 1
            assert not set(mine.ids) & set(theirs)
            with pytest.raises(BackendError, match=str(lock_dir)):
                claim_domains(1, base=100, span=4)
    finally:
        child.kill()
        child.wait(timeout=CHILD_S)


def test_a_killed_claimers_domains_come_free(lock_dir: Path) -> None:
    """``kill -9`` of the holder leaves no stale claim: the kernel drops its locks."""
    child, theirs = _child_claim(lock_dir, 1, base=50, span=1)
    with pytest.raises(BackendError, match="claimed by another process"):
        claim_domains(1, base=50, span=1)
    os.kill(child.pid, signal.SIGKILL)
    child.wait(timeout=CHILD_S)
    with claim_domains(1, base=50, span=1) as mine:
        assert mine.ids == theirs == [50]


def test_released_claims_come_free_and_alignment_is_kept() -> None:
    with claim_domains(2, base=61, span=6, align=2) as pair:
        assert pair.first % 2 == 0 and pair.ids == [pair.first, pair.first ^ 1]
    with claim_domains(2, base=61, span=6, align=2) as again:  # released: free again
        assert again.ids == pair.ids


def test_a_range_outside_ros_domains_is_refused() -> None:
    with pytest.raises(BackendError, match="0..232"):
        claim_domains(4, base=230, span=10)
    with pytest.raises(BackendError, match="no block of 3"):
        claim_domains(3, base=10, span=2)


def test_an_inherited_claim_is_not_this_process_s() -> None:
    """A domain claimed by a parent (a pytest-xdist controller) and inherited by its children
    (the workers) is claimed anew by each child; one set by hand is kept as is."""
    from fleet.ros.domains import CLAIMED_BY_ENV, ensure_private_domain

    by_hand = {"ROS_DOMAIN_ID": "7"}
    assert ensure_private_domain(by_hand) == 7 and CLAIMED_BY_ENV not in by_hand
    with claim_domains(1) as held:  # the parent's claim, still held
        parent = {"ROS_DOMAIN_ID": str(held.first), CLAIMED_BY_ENV: str(os.getppid())}
        mine = ensure_private_domain(parent)
        assert mine != held.first and parent["ROS_DOMAIN_ID"] == str(mine)
        assert parent[CLAIMED_BY_ENV] == str(os.getpid())
        assert ensure_private_domain(parent) == mine  # this process's own claim: kept
