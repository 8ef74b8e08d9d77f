"""Traffic management: the pure reservation core, wait-for cycles, and real simulated robots
driven through their NavigationBackend by :class:`fleet.traffic.TrafficFollower`."""

from __future__ import annotations

import json
import math
import random
from collections.abc import Iterable
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
import pytest

from fleet.clock import SimClock
from fleet.errors import TrafficError
from fleet.maps import OCCUPIED, OccupancyGrid
from fleet.messages import Grant
from fleet.roadmap.cells import split_cells
from fleet.roadmap.graph import Roadmap
from fleet.robots import BatteryModel, RobotSpec, SimParams
from fleet.traffic.follower import TrafficFollower
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.traffic.policy import ReservationTraffic
from fleet.traffic.reservations import ReservationTable, edge_key
from fleet.types import Pose2D
from sim.simulator import Simulator

TICK_S = 0.1  # manager / follower period (s of simulated time)

# ----------------------------------------------------------------------------- worlds


def roadmap_of(nodes: dict[str, tuple[float, float]], edges: Iterable[tuple[str, str]]) -> Roadmap:
    g = nx.Graph()
    for n, xy in nodes.items():
        g.add_node(n, pos=xy)
    g.add_edges_from(edges)
    return Roadmap.from_graph(g)


def carve_grid(rm: Roadmap, half_width: float = 0.6, margin: float = 1.5, res: float = 0.1) -> OccupancyGrid:
    """All occupied except lanes of ``half_width`` around every roadmap edge (single-lane
    corridors: two robots of radius 0.3 cannot pass each other) and squares at the nodes."""
    xy = np.array([rm.pos(n) for n in rm.nodes])
    x0, y0 = xy.min(axis=0) - margin
    x1, y1 = xy.max(axis=0) + margin
    w, h = int(math.ceil((x1 - x0) / res)), int(math.ceil((y1 - y0) / res))
    cells = np.full((h, w), OCCUPIED, dtype=np.int8)
    cx = x0 + (np.arange(w) + 0.5) * res
    cy = y0 + (np.arange(h) + 0.5) * res
    X, Y = np.meshgrid(cx, cy)
    for a, b in rm.edges:
        (ax, ay), (bx, by) = rm.pos(a), rm.pos(b)
        dx, dy = bx - ax, by - ay
        L2 = dx * dx + dy * dy
        t = np.clip(((X - ax) * dx + (Y - ay) * dy) / L2, 0.0, 1.0)
        d = np.hypot(X - (ax + t * dx), Y - (ay + t * dy))
        cells[d <= half_width] = 0
    for n in rm.nodes:
        px, py = rm.pos(n)
        cells[(np.abs(X - px) <= half_width) & (np.abs(Y - py) <= half_width)] = 0
    return OccupancyGrid(
        cells=cells, resolution=res, origin_x=float(x0), origin_y=float(y0), source="<traffic test>"
    )


def grid_roadmap(nx_: int, ny_: int, spacing: float) -> Roadmap:
    nodes = {f"n{i}_{j}": (i * spacing, j * spacing) for i in range(nx_) for j in range(ny_)}
    edges = [(f"n{i}_{j}", f"n{i + 1}_{j}") for i in range(nx_ - 1) for j in range(ny_)]
    edges += [(f"n{i}_{j}", f"n{i}_{j + 1}") for i in range(nx_) for j in range(ny_ - 1)]
    return roadmap_of(nodes, edges)


@dataclass
class World:
    """A simulator, a traffic manager and one follower per robot, stepped together."""

    sim: Simulator
    tm: TrafficManager
    followers: dict[str, TrafficFollower]
    deadlock_seen: int = 0
    max_wait_s: float = 0.0
    #: deliver grants like the bus would: only those ``cycle`` reports changed, as JSON
    over_bus: bool = False
    latest: dict[str, Grant] = field(default_factory=dict)

    def tick(self, limit_s: float = 20.0) -> None:
        now = self.sim.clock.now()
        for ns in self.followers:
            pose = self.sim.robot_state(ns).pose
            assert pose is not None
            self.tm.update(ns, pose, now)
        changed = self.tm.cycle(now)
        if self.over_bus:
            for ns in changed:
                self.latest[ns] = Grant.from_dict(json.loads(json.dumps(self.tm.grant(ns).to_dict())))
            for ns, f in self.followers.items():
                f.apply(self.latest.get(ns), now)
            return
        for ns, f in self.followers.items():
            if self.tm.is_alive(ns):
                f.apply(self.tm.grant(ns), now)
        if self.tm.deadlocked(now, limit_s):
            self.deadlock_seen += 1
        self.max_wait_s = max(self.max_wait_s, self.tm.longest_wait(now)[1])

    def run(self, seconds: float, until: object = None, check: bool = False) -> bool:
        steps_per_tick = max(1, round(TICK_S / self.sim.params.step_s))
        end = self.sim.clock.now() + seconds
        k = 0
        while self.sim.clock.now() < end - 1e-9:
            if k % steps_per_tick == 0:
                self.tick()
                if check:
                    self.tm.check()
                if callable(until) and until():
                    return True
            self.sim.step()
            k += 1
        return bool(callable(until) and until())


def make_world(
    rm: Roadmap, starts: dict[str, str], params: TrafficParams | None = None, **grid_kw: float
) -> World:
    # batteries do not drain: an hour-long patrol would otherwise empty them (and the traffic
    # manager would then, correctly, declare the stopped robots dead)
    no_drain = BatteryModel(drain_per_m=0.0, drain_per_s=0.0)
    sim = Simulator(carve_grid(rm, **grid_kw), SimParams(step_s=0.05, battery=no_drain), SimClock())
    tm = TrafficManager(rm, params or TrafficParams())
    followers = {}
    for ns, node in starts.items():
        x, y = rm.pos(node)
        sim.add_robot(RobotSpec(ns.strip("/"), ns, Pose2D(x, y, 0.0)))
        tm.add_robot(ns, Pose2D(x, y, 0.0), 0.0)
        followers[ns] = TrafficFollower(sim.backend(ns))
    return World(sim, tm, followers)


def at(world: World, ns: str, node: str, tol: float = 0.3) -> bool:
    pose = world.sim.robot_state(ns).pose
    assert pose is not None
    x, y = world.tm.node_pos(node)
    return math.hypot(pose.x - x, pose.y - y) <= tol


# ----------------------------------------------------------------------------- pure core


def test_reservation_table_never_double_books() -> None:
    rng = random.Random(7)
    table = ReservationTable()
    resources = [f"n{i}" for i in range(30)] + [edge_key(f"n{i}", f"n{i + 1}") for i in range(29)]
    robots = [f"r{i}" for i in range(12)]
    granted = 0
    for _ in range(20000):
        robot = rng.choice(robots)
        if rng.random() < 0.55:
            want = rng.sample(resources, rng.randint(1, 5))
            before = {r: table.holder(r) for r in want}
            bad = table.try_acquire(robot, want)
            if bad:
                assert all(before[r] not in (None, robot) for r in bad)
                assert all(table.holder(r) == before[r] for r in want)  # all or nothing
            else:
                granted += 1
                assert all(table.holder(r) == robot for r in want)
        elif rng.random() < 0.5:
            mine = list(table.held(robot))
            table.release(robot, rng.sample(mine, rng.randint(0, len(mine))) if mine else [])
        else:
            table.release_all(robot, keep=list(table.held(robot))[:1])
        table.check()
    assert granted > 1000


def test_random_paths_no_double_booking_and_grants_are_held() -> None:
    """Property: robots teleporting along random paths through a manager never share a
    node or an edge, and everything granted is held."""
    rm = grid_roadmap(8, 8, 2.0)
    rng = random.Random(3)
    tm = TrafficManager(rm, TrafficParams(deadlock_detect_s=1.0, detect_period_s=0.2, stall_timeout_s=1e9))
    names = [f"r{i}" for i in range(14)]
    starts = rng.sample(rm.nodes, len(names))
    pos: dict[str, Pose2D] = {}
    for n, s in zip(names, starts, strict=True):
        x, y = rm.pos(s)
        pos[n] = Pose2D(x, y)
        tm.add_robot(n, pos[n], 0.0)
        tm.set_path(n, rm.shortest_path(s, rng.choice(rm.nodes)) or [s], 0.0)
    now = 0.0
    moved = 0
    for _ in range(3000):
        now += 0.1
        for n in names:
            gr = tm.grant(n)
            if gr.nodes and rng.random() < 0.7:  # jump part way to the next granted node
                tx, ty = rm.pos(gr.nodes[0])
                p = pos[n]
                f = 1.0 if math.hypot(tx - p.x, ty - p.y) < 0.6 else 0.5
                pos[n] = Pose2D(p.x + f * (tx - p.x), p.y + f * (ty - p.y))
                moved += 1
            tm.update(n, pos[n], now)
            if tm.done(n) and rng.random() < 0.3:
                here = tm.path(n)[0]
                tm.set_path(n, rm.shortest_path(here, rng.choice(rm.nodes)), now)
        tm.cycle(now)
        tm.check()
        for n in names:
            for m in names:
                if n < m:
                    assert not (tm.held(n) & tm.held(m))
    assert moved > 5000
    assert tm.deadlocked(now, 30.0) == []


def _loops_with_deaths(seed: int) -> str | None:
    """Six robots on short patrol loops of a 5 x 5 grid, teleported along their grants; now
    and then one is declared dead (the others' loops are then topped up around it). The
    first broken reservation invariant, or ``None``."""
    rng = random.Random(seed)
    rm = grid_roadmap(5, 5, 2.0)
    tm = TrafficManager(rm, TrafficParams(stall_timeout_s=1e9, loop_min_nodes=rng.choice([3, 5, 8, 40])))
    names = [f"r{i}" for i in range(6)]
    pos: dict[str, Pose2D] = {}
    for n, s in zip(names, rng.sample(rm.nodes, len(names)), strict=True):
        x, y = rm.pos(s)
        pos[n] = Pose2D(x, y)
        tm.add_robot(n, pos[n], 0.0)
        i0, j0 = (min(int(v), 3) for v in s[1:].split("_"))
        corners = [f"n{i0}_{j0}", f"n{i0 + 1}_{j0}", f"n{i0 + 1}_{j0 + 1}", f"n{i0}_{j0 + 1}"]
        tm.set_path(n, rm.expand_route(corners, closed=True), 0.0, loop=True)
    now = 0.0
    for _ in range(600):
        now += 0.1
        for n in names:
            if not tm.is_alive(n):
                continue
            gr = tm.grant(n)
            if gr.nodes and rng.random() < 0.7:
                tx, ty = rm.pos(gr.nodes[0])
                p = pos[n]
                f = 1.0 if math.hypot(tx - p.x, ty - p.y) < 0.6 else 0.5
                pos[n] = Pose2D(p.x + f * (tx - p.x), p.y + f * (ty - p.y))
            tm.update(n, pos[n], now)
        if rng.random() < 0.01:
            victim = rng.choice(names)
            if tm.is_alive(victim):
                tm.declare_dead(victim, now)
        tm.cycle(now)
        try:
            tm.check()
        except AssertionError as e:
            return f"seed {seed}, t={now:.1f} s: {e}"
    return None


def test_looped_robots_hold_their_whole_grant_while_others_die() -> None:
    """Property: a robot whose loop is topped up around a dead robot's node (its path is
    replaced while it advances) never releases a node that lies ahead on its grant."""
    broken = [b for b in (_loops_with_deaths(seed) for seed in range(50)) if b is not None]
    assert broken == []


def _two_way_standoff() -> tuple[TrafficManager, Roadmap]:
    # a - b - c - d with a side bay s at b; A goes a->d, B goes d->a
    rm = roadmap_of(
        {"a": (0, 0), "b": (2, 0), "c": (4, 0), "d": (6, 0), "s": (2, 2)},
        [("a", "b"), ("b", "c"), ("c", "d"), ("b", "s")],
    )
    tm = TrafficManager(rm, TrafficParams(deadlock_detect_s=1.0, detect_period_s=0.1))
    tm.add_robot("A", Pose2D(0, 0), 0.0)
    tm.add_robot("B", Pose2D(6, 0), 0.0)
    tm.set_path("A", ["a", "b", "c", "d"], 0.0)
    tm.set_path("B", ["d", "c", "b", "a"], 0.0)
    return tm, rm


def test_corridor_block_is_atomic_and_its_far_junction_is_taken_separately() -> None:
    # a - b - c1 - c2 - d, side bay s at b (b is a junction). A stands in the corridor at c1
    # and leaves by b; B comes from d through the corridor c2, c1 and on to b, a.
    rm = roadmap_of(
        {"a": (0, 0), "b": (2, 0), "c1": (4, 0), "c2": (6, 0), "d": (8, 0), "s": (2, 2)},
        [("a", "b"), ("b", "c1"), ("c1", "c2"), ("c2", "d"), ("b", "s")],
    )
    tm = TrafficManager(rm, TrafficParams(follow=False))  # the strict rule: no following
    tm.add_robot("A", Pose2D(4, 0), 0.0)
    tm.add_robot("B", Pose2D(8, 0), 0.0)
    tm.set_path("A", ["c1", "b", "a"], 0.0)
    tm.set_path("B", ["d", "c2", "c1", "b", "a"], 0.0)
    tm.cycle(0.0)
    # B's block is the corridor c2, c1, all or nothing: A is in it, so B waits outside
    assert tm.grant("A").nodes[0] == "b"
    assert tm.grant("B").nodes == ()
    assert tm.blockers("B") == {"A"}
    assert tm.holder("c2") is None  # B did not take half of the corridor
    # A reaches b and leaves c1 behind: B takes the whole corridor although A still stands on
    # the junction at its far end (the junction is a block of its own, taken when B gets there)
    tm.update("A", Pose2D(2, 0), 1.0)
    tm.cycle(1.0)
    assert tm.grant("B").nodes == ("c2", "c1")
    assert tm.holder("b") == "A"
    tm.check()


def test_same_direction_robots_follow_into_a_corridor_opposite_ones_wait() -> None:
    """With following on, a robot enters a corridor behind one driving it the same way
    (node by node); one coming the other way still waits for the whole corridor."""
    rm = roadmap_of(
        {
            "a": (0, 0),
            "b": (2, 0),
            "c1": (4, 0),
            "c2": (6, 0),
            "d": (8, 0),
            "s": (2, 2),
            "t": (8, 2),
            "e": (10, 0),
        },
        [("a", "b"), ("b", "c1"), ("c1", "c2"), ("c2", "d"), ("b", "s"), ("d", "t"), ("d", "e")],
    )
    tm = TrafficManager(rm, TrafficParams())
    tm.add_robot("A", Pose2D(4, 0), 0.0)  # in the corridor at c1, driving east to e
    tm.add_robot("B", Pose2D(2, 0), 0.0)  # at b behind it, also east
    tm.set_path("A", ["c1", "c2", "d", "e"], 0.0)
    tm.set_path("B", ["b", "c1", "c2", "d", "e"], 0.0)
    tm.cycle(0.0)
    assert tm.holder("c2") == "A"
    tm.update("A", Pose2D(6, 0), 1.0)  # A reaches c2 and leaves c1 behind
    tm.cycle(1.0)
    assert tm.grant("B").nodes[:1] == ("c1",)  # B follows A into the corridor
    assert tm.holder("c2") == "A"
    tm.check()
    # C comes the other way from e into the corridor: it waits for the corridor to empty
    tm.add_robot("C", Pose2D(8, 2), 1.0)
    tm.set_path("C", ["t", "d", "c2", "c1", "b", "a"], 1.0)
    tm.cycle(1.5)
    assert tm.holder("c2") != "C" and tm.holder("c1") != "C"
    tm.check()


def _bays(cell_m: float | None) -> Roadmap:
    """A single-lane corridor w - c1 - c2 - c3 - e of 5 m bays with a bay at each end (ws,
    et), cut into cells of at most ``cell_m`` (``None``: not cut)."""
    g = roadmap_of(
        {
            "s0": (-5, 0),
            "w": (0, 0),
            "ws": (0, 2),
            "c1": (5, 0),
            "c2": (10, 0),
            "c3": (15, 0),
            "e": (20, 0),
            "et": (20, 2),
            "f": (25, 0),
        },
        [
            ("s0", "w"),
            ("w", "ws"),
            ("w", "c1"),
            ("c1", "c2"),
            ("c2", "c3"),
            ("c3", "e"),
            ("e", "et"),
            ("e", "f"),
        ],
    ).graph
    return Roadmap.from_graph(split_cells(g, cell_m, 0.9) if cell_m is not None else g)


def _follow_gap(cell_m: float | None) -> tuple[float, float, World]:
    """A drives through the corridor of :func:`_bays` towards the bay et, where D stands
    idle (A waits at e); B drives the same way behind A. The closest the two came and
    their gap at the end (m), and the world."""
    rm = _bays(cell_m)
    world = make_world(rm, {"/A": "c1", "/B": "s0", "/D": "et"}, TrafficParams(cell_m=cell_m))
    world.tm.set_path("/A", rm.shortest_path("c1", "et"), 0.0)
    world.tm.set_path("/B", rm.shortest_path("s0", "f"), 0.0)
    closest = math.inf

    def closer() -> bool:
        nonlocal closest
        a, b = world.sim.robot_state("/A").pose, world.sim.robot_state("/B").pose
        assert a is not None and b is not None
        closest = min(closest, a.distance_to(b))
        return False

    world.run(40.0, until=closer, check=True)
    a, b = world.sim.robot_state("/A").pose, world.sim.robot_state("/B").pose
    assert a is not None and b is not None
    return closest, a.distance_to(b), world


def test_with_cells_a_follower_closes_up_and_an_oncoming_robot_still_waits() -> None:
    """``TrafficParams.cell_m``: with the corridor cut into cells, a robot following another
    one the same way stops about a cell behind it, not a whole 5 m bay, and they never
    touch; a robot coming the other way still waits for the whole corridor."""
    closest, gap, world = _follow_gap(None)
    assert gap > 4.5 and world.sim.collisions == 0  # node by node: a whole bay behind A
    closest, gap, world = _follow_gap(1.5)
    assert at(world, "/A", "e")  # A waits at e for D
    assert 2 * 0.3 < closest and gap < 2.2  # B closed up to within about a cell
    assert world.sim.collisions == 0
    # the other way: A in the cut corridor drives east, C at the far end wants to go west
    # through it: C takes none of the corridor while A is in it
    rm = _bays(1.5)
    tm = TrafficManager(rm, TrafficParams(cell_m=1.5))
    tm.add_robot("A", Pose2D(10, 0), 0.0)
    tm.add_robot("C", Pose2D(20, 2), 0.0)
    tm.set_path("A", rm.shortest_path("c2", "f"), 0.0)
    tm.set_path("C", rm.shortest_path("et", "s0"), 0.0)
    tm.cycle(0.0)
    tm.cycle(0.5)
    inside = [n for n in tm.path("C") if 0 < tm.node_pos(n)[0] < 20 and tm.node_pos(n)[1] == 0]
    assert len(inside) > 10 and not any(tm.holder(n) == "C" for n in inside)
    assert tm.holder("cell:11.25,0.00") == "A"
    tm.check()


def test_wait_for_cycle_detected_and_resolved_by_side_step() -> None:
    tm, rm = _two_way_standoff()
    tm.cycle(0.0)
    tm.update("A", Pose2D(2, 0), 1.0)  # A drives to b and now wants c, d (B stands on d)
    tm.cycle(1.0)
    assert tm.waiting() == {"A", "B"}
    assert tm.blockers("A") == {"B"} and tm.blockers("B") == {"A"}
    assert tm.deadlocked(1.5, 0.4) == [frozenset({"A", "B"})]
    g = tm.wait_for_graph()
    assert sorted(sorted(c) for c in nx.simple_cycles(g)) == [["A", "B"]]
    tm.cycle(2.5)  # waited > deadlock_detect_s: resolve
    assert tm.metrics.deadlocks_detected == 1 and tm.metrics.deadlocks_resolved == 1
    # B has no way out (d is a dead end); A steps aside into the bay s
    assert tm.grant("A").nodes == ("s",)
    assert tm.path("A")[:4] == ["b", "s", "b", "c"]
    tm.update("A", Pose2D(2, 2), 3.0)
    tm.cycle(3.0)
    assert tm.grant("B").nodes[:2] == ("c", "b")  # b freed: B passes
    assert tm.grant("A").nodes == ()  # A yields until B has gone by
    tm.check()


def test_dead_robot_keeps_only_its_node_and_others_reroute() -> None:
    rm = grid_roadmap(3, 3, 2.0)
    tm = TrafficManager(rm)
    tm.add_robot("A", Pose2D(0, 0), 0.0)
    tm.add_robot("B", Pose2D(4, 4), 0.0)
    tm.set_path("A", ["n0_0", "n1_0", "n2_0", "n2_1"], 0.0)
    tm.cycle(0.0)
    assert {"n1_0", "n2_0", "n2_1"} <= tm.held("A")
    tm.update("A", Pose2D(2, 0), 1.0)  # A on n1_0
    tm.cycle(1.0)
    assert "n0_0" not in tm.held("A")  # released behind it
    tm.declare_dead("A", 2.0)
    tm.cycle(2.0)
    assert tm.held("A") == frozenset({"n1_0"})
    assert tm.grant("A").alive is False and tm.grant("A").nodes == ()
    # B wants to go through n1_0 to n0_0: rerouted around the dead robot
    tm.set_path("B", ["n2_2", "n2_1", "n2_0", "n1_0", "n0_0"], 2.0)
    tm.cycle(2.0)
    assert "n1_0" not in tm.path("B")
    assert tm.path("B")[0] == "n2_2" and tm.path("B")[-1] == "n0_0"
    assert tm.metrics.dead_reroutes >= 1


def test_stall_timeout_declares_a_robot_dead() -> None:
    rm = grid_roadmap(3, 1, 2.0)
    tm = TrafficManager(rm, TrafficParams(stall_timeout_s=5.0))
    tm.add_robot("A", Pose2D(0, 0), 0.0)
    tm.set_path("A", ["n0_0", "n1_0", "n2_0"], 0.0)
    for k in range(80):
        tm.update("A", Pose2D(0, 0), k * 0.1)
        tm.cycle(k * 0.1)
    assert not tm.is_alive("A")
    assert tm.held("A") == frozenset({"n0_0"})


def test_bad_paths_raise() -> None:
    rm = grid_roadmap(2, 2, 2.0)
    tm = TrafficManager(rm)
    tm.add_robot("A", Pose2D(0, 0), 0.0)
    with pytest.raises(TrafficError):
        tm.set_path("A", ["n0_0", "n1_1"], 0.0)  # no such edge
    with pytest.raises(TrafficError):
        tm.set_path("A", ["nowhere"], 0.0)
    with pytest.raises(TrafficError):
        tm.add_robot("B", Pose2D(0.1, 0), 0.0)  # node n0_0 is A's


def test_grant_round_trips_as_json() -> None:
    tm, _ = _two_way_standoff()
    tm.cycle(0.0)
    gr = tm.grant("A")
    assert Grant.from_dict(gr.to_dict()) == gr


def test_priority_ages_and_starving_robot_claims_its_block() -> None:
    # two robots want the junction j; the one that has waited longest goes first, and one
    # that waited past starve_s claims the block so younger robots cannot take it
    rm = roadmap_of(
        {"j": (0, 0), "w": (-2, 0), "e": (2, 0), "n": (0, 2), "s": (0, -2)},
        [("j", "w"), ("j", "e"), ("j", "n"), ("j", "s")],
    )
    tm = TrafficManager(rm, TrafficParams(starve_s=5.0, detect_period_s=0.5))
    for name, node in (("H", "j"), ("W", "w"), ("E", "e")):
        x, y = rm.pos(node)
        tm.add_robot(name, Pose2D(x, y), 0.0)
    tm.set_path("H", ["j", "n"], 0.0)
    tm.set_path("W", ["w", "j", "s"], 0.0)
    tm.cycle(0.0)  # H takes n; W waits for j (H stands on it)
    assert tm.waiting() == {"W"}
    tm.set_path("E", ["e", "j", "s"], 3.0)
    tm.cycle(3.0)
    assert tm.priority("W", 6.0) > tm.priority("E", 6.0)  # aging
    for k in range(1, 30):  # W passes starve_s: it claims j and s
        tm.cycle(3.0 + 0.25 * k)
    assert tm.claimant("j") == "W"
    tm.update("H", Pose2D(0, 2), 11.0)  # H leaves j
    tm.cycle(11.0)
    assert tm.grant("W").nodes == ("j", "s") and tm.grant("E").nodes == ()
    assert tm.blockers("E") == {"W"}
    tm.check()


def test_parked_robot_is_nudged_out_of_the_way() -> None:
    # P finished its path on m, in the middle of the only way from a to b
    rm = roadmap_of(
        {"a": (0, 0), "m": (2, 0), "b": (4, 0), "bay": (2, 2)}, [("a", "m"), ("m", "b"), ("m", "bay")]
    )
    tm = TrafficManager(rm, TrafficParams(reroute_after_s=2.0, detect_period_s=0.5))
    tm.add_robot("P", Pose2D(2, 0), 0.0)
    tm.add_robot("R", Pose2D(0, 0), 0.0)
    tm.set_path("R", ["a", "m", "b"], 0.0)
    t = 0.0
    while t < 5.0:
        t += 0.5
        tm.cycle(t)
    assert tm.metrics.nudges == 1
    assert tm.grant("P").nodes == ("bay",)
    tm.update("P", Pose2D(2, 2), 6.0)
    tm.cycle(6.0)
    assert tm.grant("R").nodes == ("m", "b")


def test_deadlocked_query_needs_everyone_waiting_long_enough() -> None:
    tm, _ = _two_way_standoff()
    tm.cycle(0.0)
    assert tm.deadlocked(0.5, 0.1) == []  # only B waits so far
    tm.update("A", Pose2D(2, 0), 1.0)
    tm.cycle(1.0)
    assert tm.deadlocked(1.5, 1.0) == []  # A has waited only 0.5 s
    assert tm.deadlocked(2.2, 1.0) == [frozenset({"A", "B"})]
    assert tm.wait_stats("B", 2.0) == (2.0, 1)


class FakeBackend:
    """A NavigationBackend stub that records goals (the follower's contract, no motion)."""

    def __init__(self, pose: Pose2D) -> None:
        from fleet.types import GoalState, GoalStatus

        self.pose = pose
        self.goals: list[tuple[str, tuple[Pose2D, ...]]] = []
        self.states: dict[str, GoalState] = {}
        self._GoalState, self._GoalStatus = GoalState, GoalStatus

    @property
    def namespace(self) -> str:
        return "/fake"

    def send_goal(self, goal: object) -> str:
        gid = f"g{len(self.goals) + 1}"
        self.goals.append((gid, tuple(goal.poses)))  # type: ignore[attr-defined]
        for k, st in self.states.items():
            if not st.status.terminal:
                self.states[k] = self._GoalState(k, st.kind, self._GoalStatus.ABORTED)
        self.states[gid] = self._GoalState(gid, "navigate_through_poses", self._GoalStatus.EXECUTING)
        return gid

    def goal_state(self, goal_id: str) -> object:
        return self.states[goal_id]

    def cancel_goal(self, goal_id: str) -> None:
        st = self.states.get(goal_id)
        if st is not None and not st.status.terminal:
            self.states[goal_id] = self._GoalState(goal_id, st.kind, self._GoalStatus.CANCELED)

    def succeed(self) -> None:
        gid = self.goals[-1][0]
        self.states[gid] = self._GoalState(gid, "navigate_through_poses", self._GoalStatus.SUCCEEDED)

    def robot_state(self) -> object:
        from fleet.types import RobotState

        return RobotState(pose=self.pose)


def _grant(path_id: int, current: str, nodes: tuple[str, ...], horizon: int, **kw: bool) -> Grant:
    xs = {"a": 0.0, "b": 2.0, "c": 4.0, "d": 6.0}
    poses = tuple(Pose2D(xs[n], 0.0) for n in nodes)
    return Grant("/fake", path_id, horizon, current, nodes, poses, **kw)


def test_follower_sends_only_the_grant_splits_turn_backs_and_cancels_when_dead() -> None:
    be = FakeBackend(Pose2D(0, 0))
    f = TrafficFollower(be, refresh_m=2.5)  # type: ignore[arg-type]
    assert f.apply(_grant(1, "a", ("b",), 1), 0.0).value == "driving"
    assert [p.x for p in be.goals[-1][1]] == [2.0]
    f.apply(_grant(1, "a", ("b",), 1), 0.1)  # idempotent
    assert len(be.goals) == 1
    f.apply(_grant(1, "a", ("b", "c", "d"), 3), 0.2)  # grown while far from the goal's end:
    assert len(be.goals) == 2  # ... the robot is 2 m from b (< refresh_m): extended now
    assert [p.x for p in be.goals[-1][1]] == [2.0, 4.0, 6.0]
    # a path that turns back at c: one goal to c, the rest after c is reached
    be.pose = Pose2D(2.0, 0.0)
    f.apply(_grant(2, "b", ("c", "b", "a"), 3), 0.3)
    assert [p.x for p in be.goals[-1][1]] == [4.0]
    be.succeed()
    assert f.apply(_grant(2, "b", ("c", "b", "a"), 3), 0.4).value == "waiting"
    be.pose = Pose2D(4.0, 0.0)
    f.apply(_grant(2, "c", ("b", "a"), 3), 0.5)
    assert [p.x for p in be.goals[-1][1]] == [2.0, 0.0]
    gid = be.goals[-1][0]
    assert f.apply(_grant(2, "c", (), 3, alive=False), 0.6).value == "stopped"
    assert be.states[gid].status.value == "canceled"


# ----------------------------------------------------------------------------- simulated robots


@pytest.mark.parametrize("over_bus", [False, True], ids=["in_process", "over_bus"])
def test_head_on_in_single_lane_aisle_resolves(over_bus: bool) -> None:
    # a0 - a1 - a2 - a3 - a4, single lane, with a passing bay p off a2
    nodes = {f"a{i}": (2.0 * i, 0.0) for i in range(5)}
    nodes["p"] = (4.0, 2.0)
    rm = roadmap_of(nodes, [(f"a{i}", f"a{i + 1}") for i in range(4)] + [("a2", "p")])
    w = make_world(rm, {"/r1": "a0", "/r2": "a4"})
    w.over_bus = over_bus  # grants reach the followers only when changed, through JSON
    w.tm.set_path("/r1", [f"a{i}" for i in range(5)], 0.0)
    w.tm.set_path("/r2", [f"a{i}" for i in range(4, -1, -1)], 0.0)
    ok = w.run(
        120.0,
        until=lambda: w.tm.done("/r1") and w.tm.done("/r2") and at(w, "/r1", "a4") and at(w, "/r2", "a0"),
        check=True,
    )
    assert ok, w.tm.metrics.events
    assert w.sim.collisions == 0
    assert w.tm.metrics.deadlocks_resolved >= 1
    assert w.tm.deadlocked(w.sim.clock.now(), 5.0) == []
    assert w.deadlock_seen == 0


@pytest.mark.parametrize("over_bus", [False, True], ids=["in_process", "over_bus"])
def test_four_way_intersection_four_robots_straight_across(over_bus: bool) -> None:
    # a plus: center X, arms of three nodes (2 m apart) to the N, E, S and W
    arms = {"N": (0, 1), "E": (1, 0), "S": (0, -1), "W": (-1, 0)}
    nodes = {"X": (0.0, 0.0)}
    edges = []
    for k, (dx, dy) in arms.items():
        prev = "X"
        for i in range(1, 4):
            nodes[f"{k}{i}"] = (2.0 * i * dx, 2.0 * i * dy)
            edges.append((prev, f"{k}{i}"))
            prev = f"{k}{i}"
    rm = roadmap_of(nodes, edges)
    opposite = {"N": "S", "S": "N", "E": "W", "W": "E"}
    starts = {f"/{k}": f"{k}2" for k in arms}
    w = make_world(rm, starts)
    w.over_bus = over_bus
    for k in arms:
        w.tm.set_path(f"/{k}", rm.shortest_path(f"{k}2", f"{opposite[k]}3"), 0.0)
    ok = w.run(
        240.0,
        until=lambda: all(w.tm.done(f"/{k}") and at(w, f"/{k}", f"{opposite[k]}3") for k in arms),
        check=True,
    )
    assert ok, w.tm.metrics.events
    assert w.sim.collisions == 0
    assert w.deadlock_seen == 0


def test_dying_robot_releases_reservations_and_other_completes_via_another_path() -> None:
    # a 3 x 3 grid, 3 m spacing: /dead stalls on the middle of the bottom row
    rm = grid_roadmap(3, 3, 3.0)
    w = make_world(rm, {"/dead": "n0_0", "/live": "n2_0"})
    w.tm.set_path("/dead", ["n0_0", "n1_0", "n1_1", "n1_2"], 0.0)
    assert w.run(30.0, until=lambda: at(w, "/dead", "n1_0", 0.4))
    assert "n1_1" in w.tm.held("/dead")  # it holds the way ahead
    w.sim.set_fault("/dead", "stalled")
    w.run(1.0)
    held_before = w.tm.held("/dead")
    assert len(held_before) > 1
    now = w.sim.clock.now()
    w.tm.declare_dead("/dead", now)
    w.tm.cycle(now)
    assert w.tm.held("/dead") == frozenset({"n1_0"})
    # /live wants to go west along the bottom row, through the dead robot's node
    w.tm.set_path("/live", ["n2_0", "n1_0", "n0_0"], now)
    ok = w.run(120.0, until=lambda: w.tm.done("/live") and at(w, "/live", "n0_0"), check=True)
    assert ok, w.tm.metrics.events
    assert "n1_0" not in w.tm.path("/live")
    assert w.sim.collisions == 0
    assert w.tm.held("/dead") == frozenset({"n1_0"})


def test_reservation_traffic_plugs_into_the_coordinator_protocol() -> None:
    from fleet.coordination.coordinator import Observation, PatrolRoute, RobotView, TrafficPolicy

    rm = grid_roadmap(3, 3, 2.0)
    got: dict[str, Grant] = {}
    pol: TrafficPolicy = ReservationTraffic(rm, deliver=lambda r, g: got.__setitem__(r, g))
    route = PatrolRoute(
        "loop", rm.poses_for(["n0_0", "n2_0", "n2_2", "n0_2"]), ("n0_0", "n2_0", "n2_2", "n0_2")
    )
    pol.on_assign("r1", route, route.poses)
    views = {"r1": RobotView("r1", obs=Observation(t=0.0, pose=Pose2D(0, 0)))}
    assert pol.cycle(0.0, views) == ()
    assert got["r1"].nodes and got["r1"].nodes[0] in ("n1_0", "n0_1")
    views["r1"].alive = False
    pol.cycle(1.0, views)
    assert got["r1"].alive is False


def test_a_dead_agents_grant_shrinks_to_its_node_after_the_timeout_and_others_route_through() -> None:
    """A robot whose agent dies keeps its whole grant for ``dead_release_s`` (it may still
    finish its last goal), then only the node it stands on; another robot's path across its
    old grant is then granted."""
    from fleet.coordination.coordinator import Observation, PatrolRoute, RobotView

    rm = grid_roadmap(5, 3, 2.0)
    pol = ReservationTraffic(rm, dead_release_s=10.0)
    route = PatrolRoute(
        "loop", rm.poses_for(["n0_1", "n4_1", "n4_2", "n0_2"]), ("n0_1", "n4_1", "n4_2", "n0_2")
    )
    pol.on_assign("dead", route, route.poses)
    views = {
        "dead": RobotView("dead", obs=Observation(t=0.0, pose=Pose2D(0, 2))),
        "live": RobotView("live", obs=Observation(t=0.0, pose=Pose2D(4, 0))),
    }
    pol.cycle(0.0, views)
    m = pol.manager
    grant = set(m.held("dead"))
    assert {"n1_1", "n2_1"} <= grant
    views["dead"].alive = False  # its agent (or bus link) is gone
    pol.cycle(1.0, views)
    assert not m.is_alive("dead") and set(m.held("dead")) == grant  # it may still be driving
    pol.cycle(10.9, views)
    assert set(m.held("dead")) == grant
    pol.cycle(11.0, views)
    assert m.held("dead") == frozenset({"n0_1"})  # only the node it stands on
    # a route across its old grant is planned and granted through it
    m.set_path("live", ["n2_0", "n2_1", "n2_2"], 11.0)
    pol.cycle(11.5, views)
    assert "n2_1" in m.path("live") and "n2_1" in m.held("live")
    m.check()


# ----------------------------------------------------------------------------- fleet scale


def patrol_fleet(
    n_robots: int, sim_seconds: float, cols: int = 15, rows: int = 15, spacing: float = 3.0, seed: int = 1
) -> tuple[World, dict[str, float]]:
    """``n_robots`` robots patrol random rectangular loops of a ``cols`` x ``rows`` grid
    roadmap (single-lane edges) for ``sim_seconds``; returns the world and fleet outcomes."""
    rm = grid_roadmap(cols, rows, spacing)
    rng = random.Random(seed)
    starts = rng.sample(rm.nodes, n_robots)
    params = TrafficParams(horizon_m=1.5 * spacing)
    w = make_world(rm, {f"/r{i}": s for i, s in enumerate(starts)}, params)
    for i, s in enumerate(starts):
        ci, cj = (int(v) for v in s[1:].split("_"))
        i0 = min(max(ci + rng.choice((-2, -1, 0)), 0), cols - 3)
        j0 = min(max(cj + rng.choice((-2, -1, 0)), 0), rows - 3)
        wi, wj = rng.choice((2, 3)), rng.choice((2, 3))
        i1, j1 = min(i0 + wi, cols - 1), min(j0 + wj, rows - 1)
        corners = [f"n{i0}_{j0}", f"n{i1}_{j0}", f"n{i1}_{j1}", f"n{i0}_{j1}"]
        if rng.random() < 0.5:
            corners.reverse()
        loop = rm.expand_route(corners, closed=True)
        w.tm.set_path(
            f"/r{i}", loop, 0.0, must_visit=[k for k, n in enumerate(loop) if n in corners], loop=True
        )
    w.run(sim_seconds, check=False)
    now = w.sim.clock.now()
    laps = sum(w.tm.laps(ns) for ns in w.followers)
    nodes = sum(w.tm.nodes_passed(ns) for ns in w.followers)
    robot_hours = n_robots * sim_seconds / 3600.0
    out = {
        "laps": float(laps),
        "nodes_passed": float(nodes),
        "laps_per_robot_hour": laps / robot_hours,
        "collisions": float(w.sim.collisions),
        "deadlocks_now": float(len(w.tm.deadlocked(now, 20.0))),
        "deadlock_ticks": float(w.deadlock_seen),
        "deadlocks_resolved": float(w.tm.metrics.deadlocks_resolved),
        "deadlocks_unresolved": float(w.tm.metrics.deadlocks_unresolved),
        "mean_wait_s": w.tm.mean_wait_s(now),
        "max_wait_s": w.max_wait_s,
        "deaths": float(w.tm.metrics.deaths),
    }
    return w, out


#: ``(robots, simulated seconds)`` of the fleet runs: 50 robots for 5 simulated minutes (every
#: robot laps at least twice and about 190 wait-for cycles are broken in that time; about 40 s of
#: wall time on a heavily loaded 2-core machine) and the issue's size, 200 robots for one
#: simulated hour (2-8 minutes of wall time, 2 cores): a scale run (``make test-scale``) with
#: a hang guard of 30 minutes.
FLEET_SIZES = [
    (50, 300.0),
    pytest.param(200, 3600.0, marks=[pytest.mark.scale, pytest.mark.timeout(1800)]),
]


@pytest.mark.parametrize(("n_robots", "sim_seconds"), FLEET_SIZES, ids=lambda v: str(int(v)))
def test_fleet_patrol_no_collisions_no_deadlocks(n_robots: int, sim_seconds: float) -> None:
    """Many robots patrolling crossing loops in both directions on single-lane edges: no
    collision, no set of robots waiting on each other for more than 20 s at any tick, no
    robot declared dead, every robot completes laps."""
    side = max(8, math.ceil(math.sqrt(4.5 * n_robots)))  # about 1 robot per 4.5 nodes
    w, out = patrol_fleet(n_robots, sim_seconds, cols=side, rows=side)
    print(out)
    assert out["collisions"] == 0
    assert out["deadlock_ticks"] == 0 and out["deadlocks_now"] == 0
    assert out["deaths"] == 0
    assert all(w.tm.laps(ns) >= 1 for ns in w.followers), {ns: w.tm.laps(ns) for ns in w.followers}
    assert out["laps_per_robot_hour"] > 20.0
    assert out["max_wait_s"] < 180.0  # nobody starves


def test_manager_with_1000_robots_keeps_reservations_exclusive_and_robots_moving() -> None:
    """1000 robots on a 1600-node roadmap, teleported along their grants (no simulator; the
    cost per cycle is measured by ``bench/bench_traffic.py``): the reservation invariants
    hold, grants let the robots move on, and no wait-for cycle stands for long."""
    rm = grid_roadmap(40, 40, 2.0)
    rng = random.Random(5)
    tm = TrafficManager(rm)
    starts = rng.sample(rm.nodes, 1000)
    pos = {}
    for i, s in enumerate(starts):
        x, y = rm.pos(s)
        pos[f"r{i}"] = Pose2D(x, y)
        tm.add_robot(f"r{i}", pos[f"r{i}"], 0.0)
        tm.set_path(f"r{i}", rm.shortest_path(s, rng.choice(rm.nodes)) or [s], 0.0)
    now = 0.0
    for k in range(200):
        now += 0.1
        for n, p in pos.items():
            gr = tm.grant(n) if rng.random() < 0.1 else None
            if gr is not None and gr.nodes:
                tx, ty = rm.pos(gr.nodes[0])
                pos[n] = Pose2D(p.x + 0.5 * (tx - p.x), p.y + 0.5 * (ty - p.y))
            tm.update(n, pos[n], now)
        tm.cycle(now)
        if k % 20 == 19:
            tm.check()
    passed = sum(tm.nodes_passed(n) for n in pos)
    assert passed > 1000, passed  # about 1700: robots keep getting grants and move on
    assert tm.deadlocked(now, 10.0) == []  # wait-for cycles are broken within seconds
