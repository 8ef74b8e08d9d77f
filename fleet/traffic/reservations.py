"""Reservable resources of the roadmap (nodes and undirected edges) and the table that never
lets two robots hold the same one."""

from __future__ import annotations

from collections.abc import Container, Iterable, Sequence

#: A reservable resource: a node name, or an undirected edge as a sorted ``(a, b)`` pair.
Resource = str | tuple[str, str]


def edge_key(a: str, b: str) -> tuple[str, str]:
    """The resource of the undirected edge between ``a`` and ``b``."""
    return (a, b) if a <= b else (b, a)


class ReservationTable:
    """Exclusive holds of resources by robots. Pure bookkeeping, no geometry.

    Invariant: every resource has at most one holder, and ``held(robot)`` is exactly the set
    of resources whose holder is ``robot``.
    """

    def __init__(self) -> None:
        self._holder: dict[Resource, str] = {}
        self._held: dict[str, set[Resource]] = {}

    def holder(self, res: Resource) -> str | None:
        """The robot holding ``res``, or ``None``."""
        return self._holder.get(res)

    def free_for(
        self, robot: str | None, resources: Iterable[Resource], skip: Container[Resource] = ()
    ) -> list[Resource]:
        """The resources of ``resources`` (in their order) that nobody or ``robot`` holds and
        that are not in ``skip``: ``[x for x in resources if holder(x) in (None, robot) and x
        not in skip]`` in one pass over the table (the charger queue asks it of every dock,
        for every queued robot, every cycle)."""
        get = self._holder.get
        return [x for x in resources if x not in skip and get(x) in (None, robot)]

    def held(self, robot: str) -> frozenset[Resource]:
        """The resources ``robot`` holds (a copy)."""
        return frozenset(self._held.get(robot, ()))

    def conflicts(self, robot: str, resources: Iterable[Resource]) -> list[Resource]:
        """The resources among ``resources`` that another robot holds."""
        h = self._holder
        return [r for r in resources if h.get(r, robot) != robot]

    def try_acquire(self, robot: str, resources: Sequence[Resource]) -> list[Resource]:
        """Acquire all of ``resources`` for ``robot`` or none: returns the conflicting ones
        (empty list = acquired). Acquiring a resource already held by ``robot`` is a no-op."""
        bad = self.conflicts(robot, resources)
        if bad:
            return bad
        mine = self._held.setdefault(robot, set())
        for r in resources:
            self._holder[r] = robot
            mine.add(r)
        return []

    def release(self, robot: str, resources: Iterable[Resource]) -> list[Resource]:
        """Release those of ``resources`` that ``robot`` holds; returns the released ones."""
        mine = self._held.get(robot)
        if not mine:
            return []
        out = []
        for r in resources:
            if r in mine:
                mine.discard(r)
                del self._holder[r]
                out.append(r)
        return out

    def release_all(self, robot: str, keep: Iterable[Resource] = ()) -> list[Resource]:
        """Release everything ``robot`` holds except ``keep``; returns the released ones."""
        mine = self._held.get(robot)
        if not mine:
            return []
        k = set(keep)
        return self.release(robot, [r for r in list(mine) if r not in k])

    def __len__(self) -> int:
        return len(self._holder)

    def check(self) -> None:
        """Raise ``AssertionError`` if the invariant is broken (for tests)."""
        n = 0
        for robot, mine in self._held.items():
            for r in mine:
                assert self._holder.get(r) == robot, (
                    f"{r!r} in held({robot}) but holder is {self._holder.get(r)}"
                )
            n += len(mine)
        assert n == len(self._holder), "holder table and per-robot sets disagree"
