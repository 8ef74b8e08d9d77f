"""Wait-for cycles and how they are broken (``docs/traffic.md``, "Why waits cannot become
permanent deadlocks").

Detection: the wait-for digraph (robot -> robots it waits for) over the robots that have
waited on the same robots for a while, and its strongly connected components of two or
more robots (networkx). Resolution, lowest priority first: reroute a member around the
others (a bounded detour), or step it aside to a free node nearby after which it yields;
if no member can move, a robot that waits on the set and stands next to it makes room.
Robots blocked by dead or parked robots: the parked robot is nudged aside, or they are rerouted."""

from __future__ import annotations

import math
from collections.abc import Callable

import networkx as nx

from fleet.traffic.grants import moves_ahead
from fleet.traffic.params import ONCOMING_NODES
from fleet.traffic.paths import install, next_must, splice
from fleet.traffic.reservations import Resource, edge_key
from fleet.traffic.state import TrackedRobot, TrafficState

#: How many of another robot's next path nodes a robot stepping aside must not stop on.
SIDESTEP_CLEAR_NODES = 12


def cycles(st: TrafficState, now: float = math.inf, min_wait: float = -math.inf) -> list[set[str]]:
    """Strongly connected components (2+ robots) of the wait-for graph restricted to the
    robots that have been waiting, on the same robots, for at least ``min_wait`` s."""
    robots = st.robots
    long = set()
    for n in st.waiting:
        r = robots[n]
        if r.wait_since is not None and now - max(r.wait_since, r.blocked_since) >= min_wait:
            long.add(n)
    edges = [(n, b) for n in long for b in robots[n].blockers if b in long]
    if not edges:
        return []
    g: nx.DiGraph[str] = nx.DiGraph()
    g.add_edges_from(edges)
    return [c for c in nx.strongly_connected_components(g) if len(c) > 1]


def head_on_pairs(st: TrafficState, now: float, min_wait: float) -> list[set[str]]:
    """Pairs of robots that have waited only on each other for at least ``min_wait`` s, each
    asking for a block that holds the node the other stands on: a head-on meeting neither
    can leave without the other moving (sorted, so the same state gives the same order)."""
    out = []
    robots = st.robots
    for n in sorted(st.waiting):
        r = robots[n]
        if (
            r.wait_since is None
            or len(r.blockers) != 1
            or now - max(r.wait_since, r.blocked_since) < min_wait
        ):
            continue
        (b,) = r.blockers
        o = robots.get(b)
        if b <= n or o is None or o.wait_since is None or o.blockers != {n}:
            continue
        if now - max(o.wait_since, o.blocked_since) < min_wait:
            continue
        if o.path[o.cur] in r.blocked_on and r.path[r.cur] in o.blocked_on:
            out.append({n, b})
    return out


def detect_and_resolve(st: TrafficState, now: float) -> None:
    """One detection pass: resolve the head-on pairs older than ``swap_detect_s`` (when
    set) and the wait-for cycles older than ``deadlock_detect_s``, then help robots blocked
    by dead or parked robots; at most ``max_resolutions`` in all."""
    p = st.params
    budget = p.max_resolutions
    found = cycles(st, now, p.deadlock_detect_s)
    if p.swap_detect_s is not None and p.swap_detect_s < p.deadlock_detect_s:
        done = {n for c in found for n in c}
        found += [c for c in head_on_pairs(st, now, p.swap_detect_s) if not c & done]
    for comp in found:
        if budget <= 0:
            break
        budget -= 1
        st.metrics.deadlocks_detected += 1
        st.log(now, f"deadlock {sorted(comp)}")
        if resolve(st, comp, now):
            st.metrics.deadlocks_resolved += 1
        else:
            st.metrics.deadlocks_unresolved += 1
    unblock(st, now, budget)


def unblock(st: TrafficState, now: float, budget: int) -> None:
    """Robots that waited ``reroute_after_s`` on robots that are all dead or parked (each at
    most once per ``reroute_after_s``): nudge a parked one aside; failing that, reroute (a
    robot with a detour limit only once it waited ``dead_wait_s``)."""
    p = st.params
    for name in sorted(st.waiting):
        if budget <= 0:
            break
        r = st.robots.get(name)
        if r is None or r.wait_since is None or now - r.wait_since < p.reroute_after_s:
            continue
        if now < r.next_reroute:
            continue
        stuck_on = [st.robots[b] for b in r.blockers if b in st.robots]
        if not stuck_on or not all(not b.alive or b.parked for b in stuck_on):
            continue
        budget -= 1
        r.next_reroute = now + p.reroute_after_s
        # a parked robot costs nobody anything to move: nudge it first; a detour costs the
        # waiting robot time and energy (a robot on its way to a charger can run flat on one)
        if any(b.parked and sidestep(st, b, {name}, now, back=False) for b in stuck_on):
            st.metrics.nudges += 1
            continue
        if r.detour_m is not None and now - r.wait_since < p.dead_wait_s:
            continue  # it cannot afford a long way round: it waits for the dead robot a while
        avoid = {x for b in stuck_on for x in st.table.held(b.name) if isinstance(x, str)}
        if reroute(st, r, avoid, now, bounded=False):
            st.metrics.dead_reroutes += 1


def _held_nodes(st: TrafficState, robots: list[TrackedRobot]) -> set[str]:
    return {x for m in robots for x in st.table.held(m.name) if isinstance(x, str)}


def resolve(st: TrafficState, comp: set[str], now: float) -> bool:
    """Make one member of the deadlocked set ``comp`` give way, lowest priority first;
    True if one did. Otherwise a robot next to the set makes room (False: retried later)."""
    members = sorted((st.robots[n] for n in comp), key=lambda r: (st.priority(r, now), -r.rank))
    strict = st.params.sidestep_clear_corridor > 0
    for v in members:
        others = [m for m in members if m is not v]
        if v.claims & {x for m in others for x in m.blocked_on}:
            # a starving robot claimed what one ahead of it needs (a follower claiming the
            # node beyond the robot it follows): the claim, not the road, is the cycle
            st.drop_claims(v)
            after_yield(st, v, others, now)
            st.log(now, f"{v.name} gave up its claims to break a deadlock")
            return True
        avoid = _held_nodes(st, others)
        if reroute(st, v, avoid, now, bounded=True):
            st.metrics.reroutes += 1
            st.log(now, f"{v.name} rerouted to break a deadlock")
            after_yield(st, v, others, now)
            return True
        if sidestep(st, v, {m.name for m in others}, now, back=True, strict=strict):
            st.metrics.sidesteps += 1
            st.log(now, f"{v.name} stepped aside to {v.path[v.g]} to break a deadlock")
            return True
    # no member found a side step clear of every corridor another robot is about to enter:
    # one steps into such a corridor after all, then (``sidestep_deep_depth``) farther away
    p = st.params
    tries = [p.sidestep_depth] if strict else []
    if p.sidestep_deep_depth > p.sidestep_depth:
        tries.append(p.sidestep_deep_depth)
    for depth in tries:
        for v in members:
            if sidestep(st, v, {m.name for m in members if m is not v}, now, back=True, depth=depth):
                st.metrics.sidesteps += 1
                st.log(now, f"{v.name} stepped aside to {v.path[v.g]} to break a deadlock")
                return True
    make_room(st, comp, members, now)
    return False


def make_room(st: TrafficState, comp: set[str], members: list[TrackedRobot], now: float) -> None:
    """No member of ``comp`` can move: move a robot that waits on the set and stands next to
    it (it frees a node a member can step aside to at the next detection)."""
    robots = st.robots
    near = {u for m in members for u in st.roads.adj[m.path[m.cur]]}
    outside = sorted(
        (
            robots[n]
            for n in st.waiting
            if n not in comp and robots[n].blockers & comp and robots[n].path[robots[n].cur] in near
        ),
        key=lambda r: (st.priority(r, now), -r.rank),
    )
    avoid = _held_nodes(st, members)
    for o in outside:
        if reroute(st, o, avoid, now, bounded=True) or sidestep(st, o, set(comp), now, back=True):
            st.metrics.sidesteps += 1
            st.log(now, f"{o.name} made room for deadlock {sorted(comp)}")
            return


def after_yield(st: TrafficState, v: TrackedRobot, others: list[TrackedRobot], now: float) -> None:
    """``v`` gave way to ``others``: for ``yield_timeout_s`` it leaves them what they wait for."""
    v.yields += 1
    mine = st.table.held(v.name)
    for m in others:
        if v.name in m.blockers:
            v.yield_to[m.name] = (frozenset(mine | m.blocked_on), now + st.params.yield_timeout_s)
            st.dirty.add(m.name)


def reroute(st: TrafficState, r: TrackedRobot, avoid: set[str], now: float, bounded: bool) -> bool:
    """Replace the path between the robot's grant end and its next must-visit node by one
    that avoids ``avoid`` (and dead robots' nodes). False if impossible or too long: at most
    ``reroute_factor * old + reroute_slack_m`` (twice that when not ``bounded``)."""
    if not r.alive or r.g >= len(r.path) - 1:
        return False
    a = r.g
    b = next_must(r, a)
    bad = set(avoid) | set(st.dead_nodes)
    bad.discard(r.path[a])
    if r.path[b] in bad:
        return False
    old = r.cum[b] - r.cum[a]
    limit = st.params.reroute_factor * old + st.params.reroute_slack_m
    seg = st.roads.shortest(r.path[a], r.path[b], bad, limit if bounded else 2.0 * limit)
    if seg is None or seg == r.path[a : b + 1]:
        return False
    splice(st, r, a, b, seg)
    return True


def _aside(
    st: TrafficState, r: TrackedRobot, others: set[str], depth: int, strict: bool = False
) -> list[str] | None:
    """Nodes from ``r``'s grant end to the nearest node within ``depth`` edges that is
    reachable over free nodes and edges and not on the next part of ``others``' paths. With
    ``sidestep_clear_corridor``, a corridor node another robot is about to enter is taken
    only when no other such node lies within ``depth`` edges, and never if ``strict``."""
    start = r.path[r.g]
    avoid: set[str] = set()
    for o in others:
        orr = st.robots.get(o)
        if orr is not None:
            avoid.update(orr.path[orr.cur : orr.cur + SIDESTEP_CLEAR_NODES])
    holder, adj, claims = st.table.holder, st.roads.adj, st.claims
    entered = _entered_corridor(st, r.name) if st.params.sidestep_clear_corridor else None
    parent: dict[str, str] = {start: start}
    frontier = [start]
    target = fallback = None
    for _ in range(int(depth)):
        nxt: list[str] = []
        for u in frontier:
            for v in adj[u]:
                if v in parent:
                    continue
                if holder(v) not in (None, r.name) or holder(edge_key(u, v)) not in (None, r.name):
                    continue
                if v in st.dead_nodes or (v in claims and claims[v] != r.name):
                    continue
                parent[v] = u
                nxt.append(v)
                if v in avoid or target is not None:
                    continue
                if entered is None or not entered(v):
                    target = v
                elif fallback is None:
                    fallback = v
        if target is not None or not nxt:
            break
        frontier = nxt
    if not strict:
        target = target or fallback
    if target is None:
        return None
    seg = [target]
    while seg[-1] != start:
        seg.append(parent[seg[-1]])
    seg.reverse()
    return seg


def _entered_corridor(st: TrafficState, robot: str) -> Callable[[str], bool]:
    """A test: whether the node is a single-lane corridor node (roadmap degree 2: an aisle's
    node or a cut edge's cell) that another live robot's next ``sidestep_clear_corridor``
    path nodes step onto. A robot stepped aside there stands in that robot's way: it waits
    to come back out while the other waits for the node it holds (a head-on pair at an
    aisle's first cell)."""
    k = int(st.params.sidestep_clear_corridor)
    if k == ONCOMING_NODES:
        idx = moves_ahead(st)
    else:
        idx = {}
        for o in st.robots.values():
            if o.alive:
                seg = o.path[o.cur : o.cur + k]
                for a, b in zip(seg, seg[1:], strict=False):
                    idx.setdefault((a, b), set()).add(o.name)
    adj, deg = st.roads.adj, st.roads.deg

    def entered(v: str) -> bool:
        if deg[v] != 2:
            return False
        for u in adj[v]:
            who = idx.get((u, v))
            if who is not None and (len(who) > 1 or robot not in who):
                return True
        return False

    return entered


def sidestep(
    st: TrafficState,
    r: TrackedRobot,
    others: set[str],
    now: float,
    back: bool,
    depth: int = 0,
    strict: bool = False,
) -> bool:
    """Move ``r`` to a free node a few edges away that is not on the next part of the
    paths of ``others`` (granted at once), then (``back``) continue its path from there to
    its next must-visit node (by the shortest way, against the flow if need be, for a robot
    with a detour limit; else with the flow); without ``back`` it ends there. ``r`` then
    yields to ``others``. ``depth``: how many edges away at most (0: ``sidestep_depth``);
    ``strict``: never into a corridor another robot is about to enter (:func:`_aside`)."""
    if not r.alive or not r.path:
        return False
    seg = _aside(st, r, others, depth or st.params.sidestep_depth, strict)
    if seg is None:
        return False
    target = seg[-1]
    res: list[Resource] = []
    for u, v in zip(seg, seg[1:], strict=False):
        res += [v, edge_key(u, v)]
    old_members = [st.robots[o] for o in others if o in st.robots]
    g_new = r.g - r.cur + len(seg) - 1
    nodes = r.path[r.cur : r.g] + seg
    must = r.must[r.cur : r.g] + [r.must[r.g]] + [False] * (len(seg) - 1)
    ret: list[str] | None = None
    b = 0
    if back and r.g < len(r.path) - 1:
        b = next_must(r, r.g)
        # a robot that cannot afford a long way (a detour limit: short of energy, on its way
        # to a charger) goes back the short way, against the flow if need be, once the robots
        # it yields to have passed, not round a loop with the flow (33 m for 4 m in one run)
        ret = st.roads.shortest(target, r.path[b], set(st.dead_nodes), flow=r.detour_m is None)
        if ret is None:
            return False
    if st.table.try_acquire(r.name, res):
        return False
    if ret is not None:
        if len(ret) > 1:
            nodes += ret[1:]
            must += [False] * (len(ret) - 2) + [r.must[b]]
        else:
            must[-1] = r.must[b]
        nodes += r.path[b + 1 :]
        must += r.must[b + 1 :]
    else:
        must[-1] = True
        r.loop = None
    install(st, r, nodes, must, granted=g_new)
    st.update_waiting(r, now)
    after_yield(st, r, old_members, now)
    return True
