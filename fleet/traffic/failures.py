"""Dead and stalled robots (``docs/traffic.md``, "Failure handling").

A dead robot keeps only what it physically occupies (the nodes within ``clearance_m`` of
it, or the edge it stands on mid-edge), or, killed with ``keep_all``, everything it holds;
the rest is released at once and every live robot's not-yet-granted path is rerouted around
the nodes it keeps; :func:`shrink` later cuts a ``keep_all`` robot down to what it occupies.
A dead robot that moves again is revived on its nearest free node."""

from __future__ import annotations

from fleet.traffic.paths import splice
from fleet.traffic.reservations import Resource, edge_key
from fleet.traffic.state import TrackedRobot, TrafficState

#: At most this many detours are spliced into one path by one :func:`avoid_dead` call.
MAX_DEAD_DETOURS = 64


def occupied(st: TrafficState, r: TrackedRobot) -> set[Resource]:
    """What ``r`` physically blocks: held nodes within ``clearance_m`` of its position, else
    the held edge it stands on (mid-edge), else the held node it last reached."""
    c2 = st.params.clearance**2
    pos = st.roads.pos
    out: set[Resource] = set()
    held = st.table.held(r.name)
    for x in held:
        if isinstance(x, str):
            px, py = pos[x]
            if (px - r.x) ** 2 + (py - r.y) ** 2 <= c2:
                out.add(x)
    if not out and r.cur < r.g:  # mid-edge, far from both ends: the edge is what it blocks
        a, b = r.path[r.cur], r.path[r.cur + 1]
        e = edge_key(a, b)
        if e in held:
            ax, ay = pos[a]
            bx, by = pos[b]
            dx, dy = bx - ax, by - ay
            L2 = dx * dx + dy * dy
            t = ((r.x - ax) * dx + (r.y - ay) * dy) / L2 if L2 > 0 else 0.0
            if 0.0 < t < 1.0:
                out.add(e)
    if not out and r.path:
        n = r.path[r.cur]
        if n in held:
            out.add(n)
    return out


def kill(st: TrafficState, r: TrackedRobot, now: float, reason: str, keep_all: bool = False) -> None:
    """Treat ``r`` as dead: it keeps what it occupies (everything with ``keep_all``), ends
    its wait, loses its path and yields; live robots are rerouted around its nodes."""
    occ = set(st.table.held(r.name)) if keep_all else occupied(st, r)
    r.alive = False
    r.occupied = frozenset(occ)
    st.metrics.deaths += 1
    st.log(now, f"{r.name} dead ({reason}); keeps {sorted(map(str, occ))}")
    st.drop_claims(r)
    for x in st.table.release_all(r.name, keep=occ):
        st.wake(x)
    for x in occ:
        if isinstance(x, str):
            st.dead_nodes[x] = r.name
    if r.wait_since is not None:
        r.wait_total += now - r.wait_since
        r.wait_events += 1
        r.wait_since = None
    st.waiting.discard(r.name)
    r.back = {x for x in occ if isinstance(x, str)}
    r.loop = None
    r.path = [r.path[r.cur]] if r.path else []
    r.must = [True] * len(r.path)
    r.cum = [0.0] * len(r.path)
    r.offset += r.cur
    r.cur = r.g = 0
    r.path_id += 1
    r.yield_to = {}
    r.blockers = set()
    r.blocked_on = set()
    r.prog_x, r.prog_y = r.x, r.y
    st.changed.add(r.name)
    for o in st.robots.values():
        if o.alive and o is not r:
            avoid_dead(st, o)


def shrink(st: TrafficState, r: TrackedRobot, now: float) -> None:
    """The dead ``r`` (killed keeping everything) keeps only what it physically occupies
    now; the rest is released and live robots are rerouted around the nodes it keeps."""
    if r.alive:
        return
    occ = occupied(st, r)
    if not occ and r.path:
        occ = {r.path[r.cur]}
    released = st.table.release_all(r.name, keep=occ)
    for x in released:
        st.wake(x)
        if isinstance(x, str) and st.dead_nodes.get(x) == r.name:
            del st.dead_nodes[x]
    for x in occ:
        if isinstance(x, str):
            st.dead_nodes[x] = r.name
    r.occupied = frozenset(occ)
    r.back = {x for x in occ if isinstance(x, str)}
    st.log(now, f"{r.name} dead: released {len(released)}, keeps {sorted(map(str, occ))}")
    st.changed.add(r.name)
    for o in st.robots.values():
        if o.alive and o is not r:
            avoid_dead(st, o)


def revive(st: TrafficState, r: TrackedRobot, now: float) -> None:
    """``r`` is alive again: it gives up what it kept while dead (no longer an obstacle
    there) and re-anchors on its nearest node if that is free (it needs a new path)."""
    r.alive = True
    for x in r.occupied:
        if isinstance(x, str) and st.dead_nodes.get(x) == r.name:
            del st.dead_nodes[x]
    r.occupied = frozenset()
    node = st.roads.nearest_node(r.x, r.y)
    if not st.table.try_acquire(r.name, [node]):
        r.back.add(node)
        r.offset += 1
        r.path, r.must, r.cum = [node], [True], [0.0]
        r.cur = r.g = 0
        r.path_id += 1
    r.prog_x, r.prog_y, r.prog_t = r.x, r.y, now
    st.log(now, f"{r.name} alive again")
    st.changed.add(r.name)
    st.dirty.add(r.name)


def avoid_dead(st: TrafficState, r: TrackedRobot, start: int | None = None) -> None:
    """Reroute the not-yet-granted part of ``r``'s path (from index ``start`` if later)
    around dead robots' nodes; a must-visit node held by a dead robot is skipped. A robot
    with a detour limit (``r.detour_m``) takes no detour longer than its way plus that limit:
    it waits before the dead robot instead (most dead robots are agents being restarted, back
    within seconds; a detour through the aisles can cost a robot short of energy more than it
    has: a chaos run drained one from 22 % to flat that way, docs/faults.md)."""
    if not st.dead_nodes or not r.alive:
        return
    dead = st.dead_nodes
    i = max(r.g, start if start is not None else r.g) + 1
    guard = 0
    while i < len(r.path) and guard < MAX_DEAD_DETOURS:
        guard += 1
        if r.path[i] not in dead:
            i += 1
            continue
        a = i - 1
        b = i
        while b < len(r.path) and (r.path[b] in dead or not r.must[b]) and b < len(r.path) - 1:
            b += 1
        if r.path[b] in dead:
            return  # the path ends on a dead robot: nothing to do but wait
        seg = st.roads.shortest(r.path[a], r.path[b], set(dead))
        if seg is None:
            return
        if r.detour_m is not None and st.roads.cost(seg, flow=False) > r.cum[b] - r.cum[a] + r.detour_m:
            return  # too far round for it: it waits for the dead robot
        splice(st, r, a, b, seg)
        st.metrics.dead_reroutes += 1
        i = a + len(seg)
