"""Path edits of the traffic manager: checking a new path, joining it to what a robot is
already granted, installing it (never taking back a granted prefix), splicing in detours,
and the poses a grant hands out along the path. Units: meters, radians, ``map`` frame."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from fleet.errors import TrafficError
from fleet.traffic.contraflow import reservable
from fleet.traffic.grants import moves_ahead
from fleet.traffic.reservations import Resource, edge_key
from fleet.traffic.roads import RoadIndex
from fleet.traffic.state import TrackedRobot, TrafficState
from fleet.types import Pose2D

#: A course is trimmed (the nodes behind the robot dropped) once it reached this index.
TRIM_AFTER = 256


def checked_path(
    roads: RoadIndex, robot: str, nodes: Sequence[str], must_visit: Iterable[int] | None, loop: bool
) -> tuple[list[str], list[bool]]:
    """``(nodes, must)`` of a path given to ``set_path`` (see there); a closed loop's repeated
    first node is dropped. Raises :class:`TrafficError` for an empty path, an unknown node, a
    missing edge, a ``must_visit`` index outside the path or a loop that does not close."""
    seq = [str(n) for n in nodes]
    if not seq:
        raise TrafficError(f"set_path({robot!r}): empty path")
    for n in seq:
        if n not in roads.pos:
            raise TrafficError(f"set_path({robot!r}): unknown roadmap node {n!r}")
    for a, b in zip(seq, seq[1:], strict=False):
        if a != b and edge_key(a, b) not in roads.length:
            raise TrafficError(f"set_path({robot!r}): no roadmap edge between {a!r} and {b!r}")
    if must_visit is None:
        must = [loop] * len(seq)
        must[-1] = True
    else:
        must = [False] * len(seq)
        for i in must_visit:
            if not -len(seq) <= i < len(seq):
                raise TrafficError(f"set_path({robot!r}): must_visit index {i} outside the path")
            must[i] = True
    if loop and len(seq) > 1 and seq[-1] == seq[0]:
        seq, must = seq[:-1], [must[0] or must[-1]] + must[1:-1]
    if loop and (len(seq) < 2 or edge_key(seq[-1], seq[0]) not in roads.length):
        raise TrafficError(f"set_path({robot!r}): a loop needs 2+ nodes, its end adjacent to its start")
    return seq, must


def join(
    roads: RoadIndex, prefix: list[str], seq: list[str], must: list[bool], loop: bool = True
) -> tuple[list[str], list[bool]]:
    """Nodes (and must flags) to append after ``prefix`` to continue on ``seq``: from where
    ``seq`` passes ``prefix[-1]`` (for a path driven once, only where no must-visit node of
    ``seq`` comes before: a task whose last stop is where the robot stands must still
    visit its first stops), else by a shortest path to ``seq[0]``. Raises
    :class:`TrafficError` if ``seq`` cannot be reached."""
    if not prefix:
        return list(seq), list(must)
    last = prefix[-1]
    for i, n in enumerate(seq):
        if n == last:
            if not loop and any(must[:i]):
                break
            return seq[i + 1 :], must[i + 1 :]
    link = roads.shortest(last, seq[0], frozenset())
    if link is None:
        raise TrafficError(f"no roadmap path from {last!r} to {seq[0]!r}")
    return link[1:] + seq[1:], [False] * (len(link) - 2) + must


class HeldByOthers:
    """The nodes some robot other than ``robot`` holds (a container for
    :meth:`RoadIndex.shortest`'s ``avoid``, looked up in the table when asked)."""

    def __init__(self, st: TrafficState, robot: str) -> None:
        self.holder = st.table.holder
        self.robot = robot

    def __contains__(self, node: object) -> bool:
        h = self.holder(node) if isinstance(node, str) else None
        return h is not None and h != self.robot


class Oncoming:
    """The steps ``(u, v)`` that another robot is about to drive the other way, ``(v, u)``,
    within its next :data:`~fleet.traffic.params.ONCOMING_NODES` path nodes (a container
    for :meth:`RoadIndex.shortest`'s ``avoid_moves``)."""

    def __init__(self, st: TrafficState, robot: str) -> None:
        self.idx = moves_ahead(st)
        self.robot = robot

    def __contains__(self, move: object) -> bool:
        if not isinstance(move, tuple):
            return False
        who = self.idx.get((move[1], move[0]))
        return who is not None and (len(who) > 1 or self.robot not in who)


def errand_way(
    st: TrafficState, r: TrackedRobot, target: str, baseline: float | None = None
) -> list[str] | None:
    """The way for ``r``, sent on an errand to ``target`` (a charger, a parking dock), when
    a shorter one than the planned way exists; ``None`` otherwise.

    The planned way finishes the grant and goes on from its end with the fleet's flow
    (edges against it cost ``1 + flow_penalty`` times their length). The errand's way may
    also turn back, from the grant's end or from the first granted node at least
    ``turn_back_m`` ahead of the robot (where it can still stop), and drive against the
    flow where nobody comes: it enters no node another robot holds and drives no step
    another robot is about to drive the other way (:class:`Oncoming`). It is taken when it
    is shorter (m); if it turns back before the grant's end, what lies beyond is released
    and the grant ends there. A robot called to a charger in the middle of its patrol's
    aisle then turns back instead of driving on around the loop (on the 6-robot warehouse
    the trips to a charger were 36 m, where robots without traffic management drove 11 m).
    Returns the node path from the grant's (new) end to ``target``.

    ``baseline`` (m, from the robot's node): the length to beat instead of the planned way's
    (a robot already on its errand: :meth:`TrafficManager.shorten_errand`). With
    ``contraflow_m`` set, a way that drives against the flow is taken only if its stretch can
    be reserved end to end (:func:`fleet.traffic.contraflow.reservable`)."""
    if not st.params.turn_back:
        return None
    cur, g = r.cur, r.g
    path, pos, roads = r.path, st.roads.pos, st.roads
    if baseline is None:
        planned = roads.shortest(path[g], target, frozenset())
        if planned is None:
            return None
        best = r.cum[g] - r.cum[cur] + roads.cost(planned, flow=False) - 1e-6
    else:
        best = baseline
    contra = st.params.contraflow_m > 0.0
    k = cur + 1
    stop2 = st.params.turn_back_m * st.params.turn_back_m
    while k < g:
        x, y = pos[path[k]]
        if (x - r.x) * (x - r.x) + (y - r.y) * (y - r.y) >= stop2:
            break
        k += 1
    held, onc = HeldByOthers(st, r.name), Oncoming(st, r.name)
    chosen: tuple[int, list[str]] | None = None
    for j in sorted({min(k, g), g}):
        way = roads.shortest(path[j], target, held, flow=False, avoid_moves=onc)
        if way is None:
            continue
        d = r.cum[j] - r.cum[cur] + roads.cost(way, flow=False)
        if d < best and (not contra or reservable(st, r, way)):
            best, chosen = d, (j, way)
    if chosen is None:
        return None
    j, way = chosen
    if j < g:
        keep: set[object] = set(path[cur : j + 1]) | r.back
        keep.update(edge_key(path[i], path[i + 1]) for i in range(cur, j) if path[i] != path[i + 1])
        drop: list[Resource] = []
        for i in range(j + 1, g + 1):
            a, b = path[i - 1], path[i]
            if a != b and edge_key(a, b) not in keep:
                drop.append(edge_key(a, b))
            if b not in keep:
                drop.append(b)
        st.release(r, drop)
        r.g = j
    return way


def install(
    st: TrafficState, r: TrackedRobot, nodes: list[str], must: list[bool], granted: int | None = None
) -> None:
    """Replace ``r``'s path by ``nodes`` whose first ``g - cur + 1`` entries are its current
    grant (kept, so nothing granted is taken back); ``granted`` overrides the index of the
    last granted node (the caller holds those resources). A new ``path_id``; the robot's
    claims and blockers are dropped and its grant is tried again this cycle."""
    keep = r.g - r.cur if granted is None else granted
    assert len(nodes) == len(must)
    st.drop_claims(r)
    r.offset += r.cur
    r.path = []
    r.must = []
    r.cum = [0.0]
    append(st.roads, r, nodes, must, first=True)
    r.cur = 0
    r.g = keep
    r.path_id += 1
    r.blockers = set()
    r.blocked_on = set()
    st.changed.add(r.name)
    st.dirty.add(r.name)
    st.update_waiting(r, st.now)


def append(
    roads: RoadIndex, r: TrackedRobot, nodes: list[str], must: list[bool], first: bool = False
) -> None:
    """Append ``nodes`` (with their must flags) to the course, extending ``cum``."""
    path, cum = r.path, r.cum
    lens = roads.length
    for n, m in zip(nodes, must, strict=True):
        if path:
            a = path[-1]
            cum.append(cum[-1] + (lens.get(edge_key(a, n), 0.0) if a != n else 0.0))
        elif not first:
            cum.append(0.0)
        path.append(n)
        r.must.append(m)
    if len(cum) > len(path):
        del cum[len(path) :]


def splice(st: TrafficState, r: TrackedRobot, a: int, b: int, seg: list[str]) -> None:
    """Replace ``path[a..b]`` by ``seg`` (``seg[0] == path[a]``, ``seg[-1] == path[b]``)."""
    nodes = r.path[r.cur : a] + seg + r.path[b + 1 :]
    if len(seg) == 1:
        mid = [r.must[a] or r.must[b]]
    else:
        mid = [r.must[a]] + [False] * (len(seg) - 2) + [r.must[b]]
    install(st, r, nodes, r.must[r.cur : a] + mid + r.must[b + 1 :])


def next_must(r: TrackedRobot, after: int) -> int:
    """Index of the first must-visit node after index ``after`` (else the path's last)."""
    for k in range(after + 1, len(r.path)):
        if r.must[k]:
            return k
    return len(r.path) - 1


def trim(r: TrackedRobot) -> None:
    """Drop the nodes before the one behind the robot (``offset`` keeps absolute indices)."""
    k = r.cur - 1
    del r.path[:k]
    del r.must[:k]
    del r.cum[:k]
    r.offset += k
    r.cur -= k
    r.g -= k


def pose_at(roads: RoadIndex, r: TrackedRobot, j: int) -> Pose2D:
    """The pose at path node ``j``, facing the next different node (or, at the end, facing
    away from the previous one)."""
    path, pos = r.path, roads.pos
    x, y = pos[path[j]]
    k = j + 1
    while k < len(path) and path[k] == path[j]:
        k += 1
    if k < len(path):
        nx_, ny_ = pos[path[k]]
        return Pose2D(x, y, math.atan2(ny_ - y, nx_ - x))
    k = j - 1
    while k >= 0 and path[k] == path[j]:
        k -= 1
    if k >= 0:
        px, py = pos[path[k]]
        return Pose2D(x, y, math.atan2(y - py, x - px))
    return Pose2D(x, y, 0.0)
