"""Growing a robot's grant by blocks, all or nothing (``docs/traffic.md``, rules 3 and 4).

A block is the next path node and, inside a single-lane corridor (roadmap degree 2), every
node to the corridor's far end; the far junction joins the block when it is a dead end or
the path's end, when ``hold_far_end`` is set, or when another robot is about to come from it
into the corridor. A robot that cannot take its next block records who it waits for; one
that waited longer than ``starve_s`` claims the block so younger robots cannot take it."""

from __future__ import annotations

from fleet.traffic.params import ONCOMING_NODES
from fleet.traffic.reservations import Resource, edge_key
from fleet.traffic.state import TrackedRobot, TrafficState


def block(st: TrafficState, r: TrackedRobot) -> list[int]:
    """Path indices of ``r``'s next block (after its grant end ``g``).

    With ``junction_with_corridor`` = K > 0, a junction (degree above 2) whose next path node
    enters a single-lane corridor in which another robot drives towards that junction is
    asked for together with the corridor's block (when that block has at least K nodes), all
    or nothing: a robot does not take the junction a robot leaving the corridor needs and
    then wait for that robot's corridor (a two-robot wait-for cycle)."""
    out = _segment(st, r, r.g + 1)
    k = st.params.junction_with_corridor
    if k > 0 and len(out) == 1:
        path, deg = r.path, st.roads.deg
        j = out[0]
        if (
            j < len(path) - 1
            and deg[path[j]] > 2
            and deg[path[j + 1]] == 2
            and path[j + 1] != path[j - 1]
            and path[j + 1] != path[j]
        ):
            seg = _segment(st, r, j + 1)
            if len(seg) >= k and _leaving_through(st, r, [path[i] for i in seg], path[j]):
                out += seg
    return out


def _leaving_through(st: TrafficState, r: TrackedRobot, nodes: list[str], junction: str) -> bool:
    """Whether another live robot holds one of the corridor ``nodes`` and its path comes to
    ``junction`` before it leaves them (it drives out of the corridor through it)."""
    table, seen = st.table, set()
    for node in nodes:
        h = table.holder(node)
        if h is None or h == r.name or h in seen:
            continue
        seen.add(h)
        o = st.robots.get(h)
        if o is None or not o.alive:
            continue
        ahead = o.path[o.cur : o.cur + len(nodes) + 2]
        if junction in ahead:
            return True
    return False


def _segment(st: TrafficState, r: TrackedRobot, j: int) -> list[int]:
    """Path indices of the block of ``r`` that starts at path index ``j``: that node and,
    inside a corridor, every node to its far end (see the module docstring)."""
    path, deg = r.path, st.roads.deg
    n = len(path)
    out = []
    while j < n:
        out.append(j)
        node = path[j]
        if deg[node] != 2 or j == n - 1 or path[j + 1] == path[j - 1] or path[j + 1] == node:
            break
        j += 1
    if len(out) > 1 and st.params.follow and following(st, r, out):
        return out[:1]  # same-direction robots ahead in the corridor: follow them node by node
    if (
        not st.params.hold_far_end
        and len(out) > 1
        and deg[path[out[-1]]] > 2
        and out[-1] < n - 1
        and not oncoming(st, r, path[out[-1]], path[out[-2]])
    ):
        out.pop()  # nobody comes the other way: the far junction is taken when reached
    return out


def following(st: TrafficState, r: TrackedRobot, out: list[int]) -> bool:
    """Whether ``r`` may take only the next node of the corridor block ``out`` (path
    indices): another robot holds part of the block, every such robot stands in it and
    drives the same way as ``r`` (its next path node lies further along the block, or it
    leaves through the block's far end), and nobody is about to come the other way from the
    far end. Node reservations then keep the followers apart, and a robot coming the other
    way still needs the whole corridor free."""
    path, table = r.path, st.table
    order = {path[j]: k for k, j in enumerate(out)}
    last = len(out) - 1
    ahead = False
    for j in out:
        h = table.holder(path[j])
        if h is None or h == r.name:
            continue
        o = st.robots.get(h)
        if o is None or not o.alive or o.cur + 1 >= len(o.path):
            return False
        here, nxt = o.path[o.cur], o.path[o.cur + 1]
        k = order.get(here)
        if k is None:
            return False
        if nxt in order:
            if order[nxt] <= k:
                return False
        elif k != last:
            return False
        ahead = True
    if not ahead:
        return False
    far = path[out[-1]]
    return st.roads.deg[far] == 2 or not oncoming(st, r, far, path[out[-2]])


def oncoming(st: TrafficState, r: TrackedRobot, far: str, last: str) -> bool:
    """Whether another live robot's next :data:`ONCOMING_NODES` path nodes go from the
    junction ``far`` into the corridor node ``last`` (the opposite way to ``r``)."""
    who = moves_ahead(st).get((far, last))
    return who is not None and (len(who) > 1 or r.name not in who)


def moves_ahead(st: TrafficState) -> dict[tuple[str, str], set[str]]:
    """``(a, b)`` -> the live robots whose next :data:`ONCOMING_NODES` path nodes step from
    ``a`` to ``b`` (made current once per cycle, ``st.dir_index``; no empty sets).

    The index is kept from cycle to cycle and only the robots whose next nodes changed are
    moved in it (most robots of a large fleet stand on the same node from one cycle to the
    next): the same index as building it anew from every live robot (``tests/fleet/traffic/
    test_moves_ahead.py`` holds the two equal)."""
    idx = st.dir_index
    if idx is None:
        idx, segs = st.dir_moves, st.dir_segs
        live = 0
        for o in st.robots.values():
            if not o.alive:
                continue
            live += 1
            seg = tuple(o.path[o.cur : o.cur + ONCOMING_NODES])
            old = segs.get(o.name)
            if old == seg:
                continue
            if old is not None:
                _unindex(idx, o.name, old)
            _index(idx, o.name, seg)
            segs[o.name] = seg
        if len(segs) != live:  # robots that died or left since
            robots = st.robots
            for name in [n for n in segs if n not in robots or not robots[n].alive]:
                _unindex(idx, name, segs.pop(name))
        st.dir_index = idx
    return idx


def _index(idx: dict[tuple[str, str], set[str]], name: str, seg: tuple[str, ...]) -> None:
    for a, b in zip(seg, seg[1:], strict=False):
        who = idx.get((a, b))
        if who is None:
            idx[(a, b)] = {name}
        else:
            who.add(name)


def _unindex(idx: dict[tuple[str, str], set[str]], name: str, seg: tuple[str, ...]) -> None:
    for a, b in zip(seg, seg[1:], strict=False):
        who = idx.get((a, b))
        if who is not None:
            who.discard(name)
            if not who:
                del idx[(a, b)]


def extend(st: TrafficState, r: TrackedRobot, now: float) -> None:
    """Grant ``r`` blocks while less than ``horizon_m`` is granted ahead (at least one block
    is asked for); on the first block it cannot take, record its blockers, register it as a
    waiter of the refused resources and (starving) claim the block."""
    if not r.alive or not r.path:
        return
    p = st.params
    table, claims, robots, name = st.table, st.claims, st.robots, r.name
    changed = False
    if r.yield_to:
        expire_yields(st, r, now)
    while r.g < len(r.path) - 1:
        if r.g > r.cur and r.cum[r.g] - r.cum[r.cur] >= p.horizon_m:
            break
        idx = block(st, r)
        path = r.path
        res: list[Resource] = []
        for j in idx:
            a, b = path[j - 1], path[j]
            res.append(b)
            if a != b:
                res.append(edge_key(a, b))
        # refused: what others hold, what live starving robots claimed, and what the robots
        # it yields to wait for
        bad = table.conflicts(name, res)
        blockers: set[str] = set()
        for x in bad:
            h = table.holder(x)
            if h is not None:
                blockers.add(h)
        for x in res:
            cl = claims.get(x)
            if cl is not None and cl != name and cl in robots and robots[cl].alive:
                bad.append(x)
                blockers.add(cl)
        for y, (conf, _) in r.yield_to.items():
            yr = robots.get(y)
            if yr is None:
                continue
            for x in res:
                if x in conf and x in yr.blocked_on:
                    bad.append(x)
                    blockers.add(y)
        if bad:
            if blockers != r.blockers:
                r.blocked_since = now
            r.blockers = blockers
            r.blocked_on = set(res)
            for x in bad:
                st.waiters.setdefault(x, set()).add(r.name)
            if r.wait_since is not None and now - r.wait_since > p.starve_s:
                claim(st, r, res)
            break
        table.try_acquire(name, res)
        r.g = idx[-1]
        changed = True
        r.blockers = set()
        r.blocked_on = set()
        st.drop_claims(r)
    if changed:
        st.changed.add(r.name)
        r.prog_t = now
    st.update_waiting(r, now)


def expire_yields(st: TrafficState, r: TrackedRobot, now: float) -> None:
    """Forget the yields of ``r`` that timed out, or whose robot died, got what it waited
    for and holds none of it any more."""
    yt = r.yield_to
    for w in list(yt):
        conf, until = yt[w]
        wr = st.robots.get(w)
        if (
            wr is None
            or not wr.alive
            or now > until
            or (not (conf & wr.blocked_on) and not any(st.table.holder(x) == w for x in conf))
        ):
            del yt[w]


def claim(st: TrafficState, r: TrackedRobot, res: list[Resource]) -> None:
    """``r`` (starving) claims every resource of ``res`` no live robot has claimed, except
    what it leaves to robots it yields to (a claim on those would undo the yield)."""
    yielded: set[Resource] = set()
    for conf, _ in r.yield_to.values():
        yielded |= conf
    for x in res:
        if x in yielded:
            continue
        c = st.claims.get(x)
        if c is None or c not in st.robots or not st.robots[c].alive:
            st.claims[x] = r.name
            r.claims.add(x)
