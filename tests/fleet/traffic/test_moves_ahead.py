"""The oncoming-robot index (``fleet.traffic.grants.moves_ahead``) kept from cycle to cycle
equals the index built anew from every live robot, on fleets whose robots move, get new
paths, patrol loops, die and come back."""

from __future__ import annotations

import math
import random

from fleet.traffic import grants
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import ONCOMING_NODES, TrafficParams
from fleet.traffic.state import TrafficState
from fleet.types import Pose2D
from tests.fleet.traffic.test_traffic import grid_roadmap


def built_anew(st: TrafficState) -> dict[tuple[str, str], set[str]]:
    """The index as it was built every cycle before it was kept (the reference)."""
    idx: dict[tuple[str, str], set[str]] = {}
    for o in st.robots.values():
        if not o.alive:
            continue
        seg = o.path[o.cur : o.cur + ONCOMING_NODES]
        for a, b in zip(seg, seg[1:], strict=False):
            idx.setdefault((a, b), set()).add(o.name)
    return idx


def _fleet(seed: int) -> int:
    """Drive a random fleet for 400 cycles, comparing the two indexes after every cycle;
    returns how many entries changed between cycles (so the test knows it moved)."""
    rng = random.Random(seed)
    rm = grid_roadmap(7, 7, 2.0)
    tm = TrafficManager(rm, TrafficParams(stall_timeout_s=1e9, detect_period_s=0.3))
    st = tm._st
    names = [f"r{i}" for i in range(12)]
    pos: dict[str, Pose2D] = {}
    for k, (n, s) in enumerate(zip(names, rng.sample(rm.nodes, len(names)), strict=True)):
        x, y = rm.pos(s)
        pos[n] = Pose2D(x, y)
        tm.add_robot(n, pos[n], 0.0)
        if k % 3 == 0:  # a patrol loop round its grid cell
            i0, j0 = (min(int(v), 5) for v in s[1:].split("_"))
            corners = [f"n{i0}_{j0}", f"n{i0 + 1}_{j0}", f"n{i0 + 1}_{j0 + 1}", f"n{i0}_{j0 + 1}"]
            tm.set_path(n, rm.expand_route(corners, closed=True), 0.0, loop=True)
        else:
            tm.set_path(n, rm.shortest_path(s, rng.choice(rm.nodes)) or [s], 0.0)
    now, moved, last = 0.0, 0, dict(built_anew(st))
    for _ in range(400):
        now += 0.1
        for n in names:
            if not tm.is_alive(n):
                if rng.random() < 0.05:
                    tm.declare_alive(n, now)
                continue
            gr = tm.grant(n)
            if gr.nodes and rng.random() < 0.7:
                tx, ty = rm.pos(gr.nodes[0])
                p = pos[n]
                f = 1.0 if math.hypot(tx - p.x, ty - p.y) < 0.6 else 0.5
                pos[n] = Pose2D(p.x + f * (tx - p.x), p.y + f * (ty - p.y))
            tm.update(n, pos[n], now)
            if tm.done(n) and rng.random() < 0.3:
                tm.set_path(n, rm.shortest_path(tm.path(n)[0], rng.choice(rm.nodes)), now)
        if rng.random() < 0.02:
            victim = rng.choice(names)
            if tm.is_alive(victim):
                tm.declare_dead(victim, now)
        tm.cycle(now)
        st.dir_index = None  # made current again after the cycle, as the next cycle would
        kept = {k: set(v) for k, v in grants.moves_ahead(st).items()}
        fresh = built_anew(st)
        assert kept == fresh, f"seed {seed}, t={now:.1f} s"
        moved += sum(1 for k in fresh.keys() | last.keys() if fresh.get(k) != last.get(k))
        last = fresh
    return moved


def test_kept_index_equals_the_index_built_anew() -> None:
    for seed in range(4):
        assert _fleet(seed) > 100
