"""Following the robots along their paths, once per manager cycle: arrival at the next
path nodes (``arrive_m``), release behind (``clearance_m``), laps, and the stall and stale
checks that declare a robot dead. This runs over every robot every cycle, so it does a few
float operations per robot and real work only for robots that moved on."""

from __future__ import annotations

from fleet.traffic.failures import avoid_dead, kill
from fleet.traffic.paths import TRIM_AFTER, append, trim
from fleet.traffic.reservations import Resource, edge_key
from fleet.traffic.state import TrackedRobot, TrafficState


def track(st: TrafficState, now: float) -> None:
    """Advance every live robot along its path, release what is behind it, check its
    progress; robots that stalled (a grant ahead, no progress for ``stall_timeout_s``) or
    went stale (no position for ``stale_timeout_s``) are killed. A robot standing at its
    grant end with path left is queued (``st.dirty``) to try its grant again every
    ``detect_period_s``."""
    p = st.params
    tol2 = p.arrive_m * p.arrive_m
    clear2 = p.clearance * p.clearance
    prog2 = p.progress_m * p.progress_m
    pos = st.roads.pos
    dirty = st.dirty
    stale = p.stale_timeout_s
    stall_s = p.stall_timeout_s
    period = p.detect_period_s
    dead: list[TrackedRobot] = []
    for r in st.robots.values():
        if not r.alive:
            continue
        x, y = r.x, r.y
        if stale is not None and now - r.last_update > stale:
            dead.append(r)
            continue
        path = r.path
        cur = cur0 = r.cur
        g = r.g
        while cur < g:
            nx_, ny_ = pos[path[cur + 1]]
            if (x - nx_) * (x - nx_) + (y - ny_) * (y - ny_) > tol2:
                break
            cur += 1
        if cur != cur0:
            r.cur = cur
            advanced(st, r, cur0, now)  # may replace the path (a loop topped up around the dead)
            path, cur, g = r.path, r.cur, r.g
        back = r.back
        if back:
            rel = None
            for n in back:
                bx, by = pos[n]
                if (x - bx) * (x - bx) + (y - by) * (y - by) > clear2:
                    rel = [n] if rel is None else rel + [n]
            if rel is not None:
                fwd = path[cur + 1 : g + 1]
                for n in rel:
                    if n not in fwd and (cur < g or n != path[cur]):
                        back.discard(n)
                        st.release(r, [n])
        if g > cur:
            px, py = r.prog_x, r.prog_y
            if (x - px) * (x - px) + (y - py) * (y - py) > prog2:
                r.prog_x, r.prog_y, r.prog_t = x, y, now
            elif now - r.prog_t > stall_s:
                dead.append(r)
        else:
            r.prog_x, r.prog_y, r.prog_t = x, y, now
            if g < len(path) - 1 and r.name not in dirty and now - r.tried_t > period:
                dirty.add(r.name)
    for r in dead:
        kill(st, r, now, "stalled" if r.g > r.cur else "no position updates")


def advanced(st: TrafficState, r: TrackedRobot, cur0: int, now: float) -> None:
    """``r`` reached path nodes ``cur0 + 1 .. cur``: count them, release the edges behind
    it (unless ahead on its grant), top up a loop, and try its grant again."""
    path = r.path
    rel: list[Resource] = []
    for j in range(cur0, r.cur):
        a, b = path[j], path[j + 1]
        r.back.add(a)
        if a != b:
            rel.append(edge_key(a, b))
    r.back.add(path[r.cur])
    r.passed += r.cur - cur0
    for j in range(cur0 + 1, r.cur + 1):
        if r.must[j]:
            r.must_passed += 1
    fwd_edges = {edge_key(path[j], path[j + 1]) for j in range(r.cur, r.g)}
    st.release(r, [e for e in rel if e not in fwd_edges])
    if r.loop is not None:
        extend_loop(st, r)
    if r.cur > TRIM_AFTER:
        trim(r)
    st.dirty.add(r.name)
    st.changed.add(r.name)  # ``current`` and ``nodes`` of its grant moved on
    st.update_waiting(r, now)


def extend_loop(st: TrafficState, r: TrackedRobot) -> None:
    """Append whole laps to a looped path until ``loop_min_nodes`` lie beyond the grant
    (rerouted around dead robots' nodes)."""
    assert r.loop is not None
    seq, must = r.loop
    # invariant: the path of a looped robot ends at seq[-1], so a whole lap follows it
    while len(r.path) - r.g < st.params.loop_min_nodes:
        base = len(r.path)
        append(st.roads, r, list(seq), list(must))
        if st.dead_nodes:
            avoid_dead(st, r, start=base - 1)
