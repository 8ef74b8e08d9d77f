"""The compiled kernels compute the very floats of the NumPy code they replace, and a fleet
run compiled is the same run, bit for bit, as the same fleet run with the NumPy code (what a
machine without numba runs)."""

from __future__ import annotations

import functools
import math
import tempfile
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.types import NavigateThroughPoses, NavigateToPose, Pose2D
from fleet.warehouse import generate_warehouse
from sim import kernels
from sim.avoidance import AVOID_CLEAR_M, CORRIDOR_MARGIN_M, OFFSETS, corridor_min_numpy, pair_blocks_numpy
from sim.goals import TERMINAL
from sim.simulator import Simulator


def _gaps(along: np.ndarray, lateral: np.ndarray, contact: float) -> np.ndarray:
    inner = along - np.sqrt(np.maximum(contact * contact - lateral * lateral, 0.0))
    return np.maximum(0.0, np.where(lateral >= contact, along - contact, inner))


def _scene(seed: int, n: int, span: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Directed pairs of ``n`` robots scattered over ``span`` m (every ordered pair)."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.0, span, n), rng.uniform(0.0, span, n)
    i, j = np.nonzero(~np.eye(n, dtype=bool))
    dx, dy = x[j] - x[i], y[j] - y[i]
    return i.astype(np.int64), dx, dy, dx * dx + dy * dy


def _pair_blocks_numpy(
    a_all: np.ndarray, dx_all: np.ndarray, dy_all: np.ndarray, d2_all: np.ndarray, reach: float,
    loc: np.ndarray, db: np.ndarray, contact: float, lat: float, nb: int,
) -> np.ndarray:  # fmt: skip
    """The exact corridor test of every (pair, offset) as whole-array NumPy."""
    sel = np.flatnonzero((d2_all < reach * reach) & (loc[a_all] >= 0))
    a, dx, dy = loc[a_all[sel]], dx_all[sel], dy_all[sel]
    kk = OFFSETS.size
    p = np.repeat(np.arange(a.size), kk)
    k = np.tile(np.arange(kk), a.size)
    h = db[a[p]] + OFFSETS[k]
    hx, hy = np.cos(h), np.sin(h)
    along = dx[p] * hx + dy[p] * hy
    lateral = np.abs(dx[p] * hy - dy[p] * hx)
    hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < AVOID_CLEAR_M + contact))
    bad = hit[_gaps(along[hit], lateral[hit], contact) < AVOID_CLEAR_M]
    out = np.zeros(nb, dtype=np.int64)
    np.bitwise_or.at(out, a[p[bad]], np.left_shift(1, k[bad]))
    return out


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 60),
    span=st.floats(0.5, 6.0),
    radius=st.floats(0.1, 0.4),
)
def test_pair_blocks_is_the_exact_corridor_test(seed: int, n: int, span: float, radius: float) -> None:
    a_all, dx, dy, d2 = _scene(seed, n, span)
    rng = np.random.default_rng(seed + 1)
    contact = 2.0 * radius
    lat = contact + CORRIDOR_MARGIN_M
    reach = math.hypot(AVOID_CLEAR_M + contact, lat)
    fb = np.flatnonzero(rng.random(n) < 0.7)
    loc = np.full(n, -1, dtype=np.int64)
    loc[fb] = np.arange(fb.size)
    db = rng.uniform(-math.pi, math.pi, fb.size)
    got = np.zeros(fb.size, dtype=np.int64)
    bits = np.left_shift(1, np.arange(OFFSETS.size, dtype=np.int64))
    kernels.pair_blocks(
        a_all, dx, dy, d2, reach * reach, loc, db, OFFSETS, bits, contact, lat, AVOID_CLEAR_M, got
    )
    want = _pair_blocks_numpy(a_all, dx, dy, d2, reach, loc, db, contact, lat, fb.size)
    assert got.tolist() == want.tolist()
    fallback = np.zeros(fb.size, dtype=np.int64)
    pair_blocks_numpy(
        a_all, dx, dy, d2, reach * reach, loc, db, OFFSETS, bits, contact, lat, AVOID_CLEAR_M, fallback
    )
    assert fallback.tolist() == want.tolist()


def _edge_scene(seed: int, contact: float, lat: float) -> tuple[np.ndarray, ...]:
    """Neighbors of 20 robots placed on the thresholds of the corridor test of one of their
    detour headings (along 0 or the corridor's length, across the half-width or the contact
    distance, a gap of exactly the clearance), each nudged by 0 to a few ulp or by 1e-9 m
    either way, plus random neighbors: the inputs where a rounding could flip a decision."""
    rng = np.random.default_rng(seed)
    nb = 20
    db = rng.uniform(-math.pi, math.pi, nb)
    lim = AVOID_CLEAR_M + contact
    inner = math.sqrt(contact * contact - (0.5 * contact) ** 2)
    spots = [
        (0.0, 0.3), (lim, 0.2), (0.5, lat), (0.5, contact), (0.4, -lat), (0.4, -contact),
        (AVOID_CLEAR_M + inner, 0.5 * contact), (AVOID_CLEAR_M + contact, 1.2 * contact),
    ]  # fmt: skip
    a, dxs, dys = [], [], []
    for r in range(nb):
        laterals = rng.uniform(0.05 * contact, 0.95 * contact, 6).tolist()
        on_gap = [(AVOID_CLEAR_M + math.sqrt(contact * contact - lat_ * lat_), lat_) for lat_ in laterals]
        for along, across in spots + on_gap:
            h = db[r] + OFFSETS[rng.integers(OFFSETS.size)]
            hx, hy = math.cos(h), math.sin(h)
            for nudge in (0.0, 1e-9, -1e-9, 4e-16, -4e-16, 1e-15):
                al = along + nudge
                a.append(r)
                dxs.append(al * hx - across * hy)
                dys.append(al * hy + across * hx)
        for _ in range(5):
            a.append(r)
            dxs.append(rng.uniform(-1.5, 1.5))
            dys.append(rng.uniform(-1.5, 1.5))
    dx, dy = np.array(dxs), np.array(dys)
    return np.array(a, dtype=np.int64), dx, dy, dx * dx + dy * dy, db


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), radius=st.floats(0.1, 0.4), edges=st.booleans())
def test_rotated_detour_test_sets_the_exact_bits(seed: int, radius: float, edges: bool) -> None:
    """The detour pass's pair test from one cos / sin per robot (the neighbors turned into
    the wanted heading's frame, the exact test near any threshold) sets the very bits of the
    exact corridor test of every (pair, heading), on random crowds and on neighbors placed on
    the test's thresholds to within a few ulp."""
    from sim.detour_kernels import _rotated_blocks

    contact = 2.0 * radius
    lat = contact + CORRIDOR_MARGIN_M
    reach = math.hypot(AVOID_CLEAR_M + contact, lat)
    if edges:
        a_all, dx, dy, d2, db = _edge_scene(seed, contact, lat)
        nb = db.size
        loc = np.arange(nb, dtype=np.int64)
    else:
        n = 60
        a_all, dx, dy, d2 = _scene(seed, n, 3.0)
        rng = np.random.default_rng(seed + 1)
        fb = np.flatnonzero(rng.random(n) < 0.7)
        nb = fb.size
        loc = np.full(n, -1, dtype=np.int64)
        loc[fb] = np.arange(nb)
        db = rng.uniform(-math.pi, math.pi, nb)
    bits = np.left_shift(1, np.arange(OFFSETS.size, dtype=np.int64))
    want = np.zeros(nb, dtype=np.int64)
    kernels.pair_blocks(
        a_all, dx, dy, d2, reach * reach, loc, db, OFFSETS, bits, contact, lat, AVOID_CLEAR_M, want
    )
    got = np.zeros(nb, dtype=np.int64)
    _rotated_blocks(
        a_all, dx, dy, d2, reach * reach, loc, db, np.cos(db), np.sin(db), OFFSETS, np.cos(OFFSETS), np.sin(OFFSETS), bits, contact,
        lat, AVOID_CLEAR_M, got,
    )  # fmt: skip
    assert got.tolist() == want.tolist()
    assert want.any()  # the scenes block some headings


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 60), span=st.floats(0.5, 8.0))
def test_corridor_min_is_the_numpy_minimum(seed: int, n: int, span: float) -> None:
    a, dx, dy, _ = _scene(seed, n, span)
    rng = np.random.default_rng(seed + 2)
    th = rng.uniform(-math.pi, math.pi, n)
    moving = rng.random(n) < 0.8  # the others have heading (0, 0), as corridor_free gives them
    hx, hy = np.where(moving, np.cos(th), 0.0), np.where(moving, np.sin(th), 0.0)
    cap = rng.uniform(0.1, 2.0, n)
    contact, lat = 0.6, 0.65
    got = cap.copy()
    kernels.corridor_min(a, dx, dy, dx * dx + dy * dy, math.inf, hx, hy, cap, contact, lat, got)
    want = cap.copy()
    along = dx * hx[a] + dy * hy[a]
    lateral = np.abs(dx * hy[a] - dy * hx[a])
    hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < cap[a] + contact))
    np.minimum.at(want, a[hit], _gaps(along[hit], lateral[hit], contact))
    assert got.tobytes() == want.tobytes()
    fallback = cap.copy()
    corridor_min_numpy(a, dx, dy, hx, hy, cap, contact, lat, fallback)
    assert fallback.tobytes() == want.tobytes()


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 80), span=st.floats(0.5, 8.0))
def test_short_pairs_are_numpys_offsets_and_short_list(seed: int, n: int, span: float) -> None:
    a, _, _, _ = _scene(seed, n, span)
    rng = np.random.default_rng(seed + 3)
    x, y = rng.uniform(0.0, span, n), rng.uniform(0.0, span, n)
    b = np.array([j for i in range(n) for j in range(n) if j != i], dtype=np.int64)
    m = a.size
    sdx, sdy, sd2 = (np.empty(m) for _ in range(3))
    si, sj = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    short = 0.4 * span
    k = kernels.short_pairs(a, b, x, y, short * short, si, sj, sdx, sdy, sd2)
    ex, ey = x[b] - x[a], y[b] - y[a]
    e2 = ex * ex + ey * ey
    near = np.flatnonzero(e2 < short * short)
    assert k == near.size
    assert si[:k].tolist() == a[near].tolist() and sj[:k].tolist() == b[near].tolist()
    assert sd2[:k].tobytes() == e2[near].tobytes() and sdx[:k].tobytes() == ex[near].tobytes()
    assert sdy[:k].tobytes() == ey[near].tobytes()


def test_every_pairs_offsets_on_demand_are_those_of_the_step_start() -> None:
    """Compiled, the neighbor list stores only the short list each step; the offsets of every
    pair, asked for after the robots moved, are those of the positions at the step's start."""
    from sim.spatial import NeighborPairs

    rng = np.random.default_rng(5)
    x, y = rng.uniform(0.0, 8.0, 80), rng.uniform(0.0, 8.0, 80)
    fast, slow = NeighborPairs(2.2, 1.5, 1.0, compiled=True), NeighborPairs(2.2, 1.5, 1.0)
    fast.update(x.copy(), y.copy(), 1, 0.05)
    slow.update(x.copy(), y.copy(), 1, 0.05)
    x += 0.3  # the move of the step: the pairs' offsets are those of its start
    for name in ("si", "sj", "sdx", "sdy", "sd2", "i", "dx", "dy", "d2"):
        assert getattr(fast, name).tobytes() == getattr(slow, name).tobytes(), name
    assert fast.index_pairs(2.0)[0].tobytes() == slow.i.tobytes()


def test_libm_trigonometry_matches_numpy() -> None:
    """The kernels' ``math.cos`` / ``math.sin`` / ``math.sqrt`` give NumPy's bits here (what
    bit-identical results rest on)."""
    x = np.random.default_rng(7).uniform(-20.0, 20.0, 200_000)
    assert np.cos(x).tobytes() == np.array([math.cos(v) for v in x.tolist()]).tobytes()
    assert np.sin(x).tobytes() == np.array([math.sin(v) for v in x.tolist()]).tobytes()
    ax = np.abs(x)
    assert np.sqrt(ax).tobytes() == np.array([math.sqrt(v) for v in ax.tolist()]).tobytes()


def _fleet(tmp: str, compiled: bool) -> tuple[Simulator, list[str], list[tuple[Pose2D, ...]]]:
    cfg = load_config(generate_warehouse(tmp, "kernels", 60), robots=60)
    sim = Simulator(cfg.grid, cfg.sim, SimClock(), compiled=compiled)
    for spec in cfg.robots:
        sim.add_robot(spec)
    return sim, sim.namespaces, [cfg.route_poses(r) for r in cfg.routes]


def test_compiled_and_numpy_fleets_run_bit_identical(tmp_path: object) -> None:
    """60 robots patrolling a generated warehouse (vias, detours in the aisles, arrivals with a
    final turn, a dynamic obstacle dropped in and taken away), compiled and NumPy side by side:
    every robot's state and every goal's batch row are the same bytes after every step."""
    fast, nss, routes = _fleet(str(tmp_path / "a"), compiled=True)
    slow, _, _ = _fleet(str(tmp_path / "b"), compiled=False)
    assert fast.compiled and not slow.compiled
    goals: list[list[str]] = [[], []]
    for sim, ids in ((fast, goals[0]), (slow, goals[1])):
        for i, ns in enumerate(nss):
            goal = NavigateThroughPoses(routes[i % len(routes)])
            if i % 3 == 0:  # a single pose: arrives, then turns to the final yaw
                p = routes[i % len(routes)][1]
                goal = NavigateToPose(Pose2D(p.x, p.y, p.theta + 2.0))
            ids.append(sim.send_goal(ns, goal))
    moved = 0.0
    for k in range(360):
        if k == 60:
            p = fast.true_pose(nss[5])
            oids = [sim.add_obstacle(p.x + 1.0, p.y, 0.3) for sim in (fast, slow)]
        if k == 200:
            for sim, oid in zip((fast, slow), oids, strict=True):
                sim.remove_obstacle(oid)
        for sim in (fast, slow):
            sim.step()
        a, b = fast.robot_table(), slow.robot_table()
        for name in ("x", "y", "theta", "v", "w", "battery", "distance_m", "collisions", "stuck"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (k, name)
        if k % 5 == 0:
            qa, qb = fast.query_batch(nss, goals[0]), slow.query_batch(nss, goals[1])
            for name in ("goal_status", "goal_error", "distance_remaining"):
                assert getattr(qa, name).tobytes() == getattr(qb, name).tobytes(), (k, name)
            for i in TERMINAL[qa.goal_status].nonzero()[0].tolist():
                for sim, ids in ((fast, goals[0]), (slow, goals[1])):
                    ids[i] = sim.send_goal(nss[i], NavigateThroughPoses(routes[i % len(routes)]))
        moved = float(a.distance_m.sum())
    assert moved > 100.0  # the fleet drove: the comparison covered motion, not robots at rest


def test_numpy_code_is_chosen_by_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: object) -> None:
    monkeypatch.setenv(kernels.ENV_VAR, "numpy")
    assert not kernels.enabled()
    cfg = load_config(generate_warehouse(str(tmp_path), "env", 2), robots=2)
    assert not Simulator(cfg.grid, cfg.sim, SimClock()).compiled
    monkeypatch.setenv(kernels.ENV_VAR, "")
    assert kernels.enabled() == kernels.available()
    assert Simulator(cfg.grid, cfg.sim, SimClock()).compiled == kernels.available()


def test_kernels_that_cannot_compile_leave_the_numpy_code_running(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, tmp_path: object
) -> None:
    """numba installed but unable to compile here: a warning, and simulators run NumPy."""
    from sim import follower_kernels

    def broken() -> None:
        raise RuntimeError("no LLVM here")

    monkeypatch.setattr(kernels, "_ready", None)
    monkeypatch.setattr(kernels, "_warm_ups", [follower_kernels.warm_up, broken])
    with caplog.at_level("WARNING", logger="sim.kernels"):
        sim, nss, routes = _fleet(str(tmp_path), compiled=True)
    assert not sim.compiled and not kernels.enabled()
    assert "no LLVM here" in caplog.text and "NumPy" in caplog.text
    for i, ns in enumerate(nss):
        sim.send_goal(ns, NavigateThroughPoses(routes[i % len(routes)]))
    for _ in range(60):
        sim.step()
    assert sim.robot_table().distance_m.sum() > 10.0


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), span=st.floats(0.5, 40.0), r=st.floats(0.2, 3.0)
)
def test_compiled_neighbor_pairs_are_numpys_pairs_in_numpys_order(
    seed: int, n: int, span: float, r: float
) -> None:
    from sim.spatial import neighbor_pairs

    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-span, span, n), rng.uniform(0.0, span, n)
    if n > 3:
        x[1], y[1] = x[0], y[0] + r  # a pair at exactly the radius: not a neighbor
    want = neighbor_pairs(x, y, r)
    got = neighbor_pairs(x, y, r, compiled=True)
    assert got[0].tolist() == want[0].tolist() and got[1].tolist() == want[1].tolist()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 120), sites=st.integers(0, 12))
def test_battery_and_progress_compiled_is_the_numpy_upkeep(seed: int, n: int, sites: int) -> None:
    """Batteries (drain, charging beside a charger, the 0 and 1 bounds) and the progress
    checker (made progress, still trying, stuck) compiled and NumPy on random fleets: the same
    bytes and the same stuck robots."""
    from fleet.robots import SimParams
    from sim.state import FleetState
    from sim.upkeep import Upkeep

    rng = np.random.default_rng(seed)
    params = SimParams()
    chargers = rng.uniform(0.0, 10.0, (sites, 2))
    states = []
    for _ in range(2):
        s = FleetState()
        for _ in range(n):
            s.add(0.0, 0.0, 0.0, 0.5, 0.0)
        states.append(s)
    r2 = np.random.default_rng(seed + 1)
    cols = {
        "x": r2.uniform(0.0, 10.0, n),
        "y": r2.uniform(0.0, 10.0, n),
        "battery": np.where(r2.random(n) < 0.5, r2.choice([0.0, 1e-4, 0.9995, 1.0], n), r2.random(n)),
        "px": r2.uniform(0.0, 10.0, n),
        "py": r2.uniform(0.0, 10.0, n),
        # around the moment a robot trying to move becomes stuck
        "pt": 40.0 - params.stuck_time_s + r2.choice([-0.5, -1e-10, 0.0, 1e-10, 0.5], n),
        "has_task": r2.random(n) < 0.7,
        "drives": r2.random(n) < 0.5,
        "fol": r2.random(n) < 0.5,
        "f_xy": r2.random(n) < 0.3,
        "stuck": r2.random(n) < 0.2,
    }
    near = r2.random(n) < 0.4  # some robots on a charger, some at their progress mark
    if sites:
        k = r2.integers(0, sites, n)
        cols["x"] = np.where(near, chargers[k, 0] + 0.1, cols["x"])
        cols["y"] = np.where(near, chargers[k, 1], cols["y"])
    cols["px"] = np.where(r2.random(n) < 0.5, cols["x"] + 0.05, cols["px"])
    cols["py"] = np.where(r2.random(n) < 0.5, cols["y"], cols["py"])
    for s in states:
        for name, v in cols.items():
            getattr(s, name)[:n] = v
    moved = r2.random(n) < 0.5
    w = np.where(r2.random(n) < 0.5, 0.0, 0.3)
    ds = np.where(moved, r2.uniform(-0.05, 0.05, n), 0.0)
    stuck = [
        Upkeep(s, params, chargers, compiled).update(moved, w, ds, 0.05, 40.0)
        for s, compiled in zip(states, (True, False), strict=True)
    ]
    assert stuck[0].tolist() == stuck[1].tolist()
    a, b = states
    for name in ("battery", "charging", "px", "py", "pt", "stuck"):
        assert getattr(a, name)[:n].tobytes() == getattr(b, name)[:n].tobytes(), name


@settings(max_examples=25, deadline=None)
@example(seed=324, n=2)  # no robot of the draw has a way to test: an empty set, not an error
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 150))
def test_compiled_detour_and_way_tests_are_the_numpy_ones(seed: int, n: int) -> None:
    """The detour search (neighbors and static map in one compiled pass) and the follower's
    corridor test of the way ahead, on robots crowded into a generated warehouse's aisles
    (beside shelves, so the static samples decide headings): the same detour for every robot,
    the same side memory and the same blocked robots as the NumPy code."""
    from sim.avoidance import Avoidance
    from sim.follower import PathFollower
    from sim.footprint import FootprintGrid
    from sim.simulator import pair_radii
    from sim.spatial import NeighborPairs
    from sim.state import FleetState

    cfg, footprint = _warehouse()
    rng = np.random.default_rng(seed)
    free_iy, free_ix = np.nonzero(~footprint)
    pick = rng.choice(free_iy.size, n)
    g = cfg.grid
    x = g.origin_x + (free_ix[pick] + rng.random(n)) * g.resolution
    y = g.origin_y + (free_iy[pick] + rng.random(n)) * g.resolution
    out = []
    for compiled in (True, False):
        state = FleetState()
        for k in range(n):
            state.add(float(x[k]), float(y[k]), 0.0, 1.0, 0.0)
        radius, short = pair_radii(cfg.sim)
        pairs = NeighborPairs(radius, short, cfg.sim.model.max_linear_speed, compiled)
        pairs.update(state.x[:n], state.y[:n], 1, cfg.sim.step_s)
        fp = FootprintGrid(cfg.grid, footprint, AVOID_CLEAR_M)
        av = Avoidance(state, pairs, fp, cfg.sim.model.radius, compiled)
        fol = PathFollower(state, cfg.sim, av, compiled)
        r2 = np.random.default_rng(seed + 9)
        fi = np.flatnonzero(r2.random(n) < 0.8)
        desired = r2.uniform(-math.pi, math.pi, fi.size)
        rem = r2.uniform(0.0, 4.0, fi.size)
        side = r2.integers(-1, 2, fi.size)
        fol._avoid(fi, desired, rem, side, np.zeros((0, 3)))
        k = av.detour(
            fi, r2.uniform(-math.pi, math.pi, fi.size), r2.integers(-1, 2, fi.size), np.zeros((0, 3))
        )
        out.append((desired.tobytes(), side.tolist(), k.tolist()))
    assert out[0] == out[1]


@functools.lru_cache(maxsize=1)
def _warehouse() -> tuple[Any, np.ndarray]:
    """A generated 200-robot warehouse's config and its robots' footprint grid."""
    cfg = load_config(generate_warehouse(tempfile.mkdtemp(prefix="detour_"), "detour", 200), robots=200)
    return cfg, Simulator(cfg.grid, cfg.sim, SimClock(), compiled=False).planner.footprint


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(40, 200))
def test_compiled_segment_test_is_the_numpy_one(seed: int, n: int) -> None:
    """The planner's segment test compiled (:mod:`sim.planner_kernels`) and NumPy on random
    segments over a generated warehouse (shelves, the map's edge and beyond, zero-length and
    long segments, both grids): the same answer for every segment."""
    from sim.planner import GridPlanner

    cfg, _ = _warehouse()
    g = cfg.grid
    fast = GridPlanner(g, cfg.sim.model.radius, compiled=True)
    slow = GridPlanner(g, cfg.sim.model.radius)
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = g.extent
    ax, bx = rng.uniform(xmin - 1.0, xmax + 1.0, (2, n))
    ay, by = rng.uniform(ymin - 1.0, ymax + 1.0, (2, n))
    short = rng.random(n) < 0.6  # most segments a plan tests are short
    bx = np.where(short, ax + rng.uniform(-3.0, 3.0, n), bx)
    by = np.where(short, ay + rng.uniform(-3.0, 3.0, n), by)
    bx[0], by[0] = ax[0], ay[0]
    answers = []
    for p in (fast, slow):
        answers.append(
            [
                p.segment_free((a, b), (c, d), grid)
                for a, b, c, d in zip(ax.tolist(), ay.tolist(), bx.tolist(), by.tolist(), strict=True)
                for grid in (None, p.footprint)
            ]
        )
    assert answers[0] == answers[1]
    assert any(answers[0]) and not all(answers[0])  # both kinds of answer were compared


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 150), span=st.floats(0.5, 10.0))
def test_compiled_contacts_are_the_numpy_ones(seed: int, n: int, span: float) -> None:
    """Robots crowded together and walking at random, pairs starting and stopping to touch:
    :class:`sim.safety.Contacts` counts the same collision events, robot counts and event
    records compiled (:func:`sim.kernels.touching_pairs`) and with NumPy, step after step."""
    from fleet.robots import SimParams
    from sim.safety import Contacts
    from sim.simulator import pair_radii
    from sim.spatial import NeighborPairs
    from sim.state import FleetState

    params = SimParams()
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.0, span, n), rng.uniform(0.0, span, n)
    results = []
    for compiled in (True, False):
        state = FleetState()
        for k in range(n):
            state.add(float(x[k]), float(y[k]), 0.0, 1.0, 0.0)
        radius, short = pair_radii(params)
        pairs = NeighborPairs(radius, short, params.model.max_linear_speed, compiled)
        contacts = Contacts(state, params, pairs, compiled)
        walk = np.random.default_rng(seed + 1)
        for step in range(1, 6):
            pairs.update(state.x[:n], state.y[:n], step, params.step_s)
            state.x[:n] += walk.uniform(-0.05, 0.05, n)  # the move after the pairs were found
            state.y[:n] += walk.uniform(-0.05, 0.05, n)
            contacts.count(0.05 * step, lambda i: f"/r{i}")
        results.append((contacts.total, contacts.events, state.collisions[:n].tolist()))
    assert results[0] == results[1]
    if n >= 100 and span <= 2.0:
        assert results[0][0] > 0  # a crowd this dense touches: events were compared


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), discs=st.integers(0, 12))
def test_compiled_search_plans_the_python_paths(seed: int, discs: int) -> None:
    """The planner's A* compiled (:func:`sim.planner_kernels.astar`) and in Python, from
    random free starts to random goals on a generated warehouse, around random learned
    obstacles (which close aisles) and without: the same result, path and error code."""
    from sim.planner import GridPlanner

    cfg, footprint = _warehouse()
    g = cfg.grid
    fast = GridPlanner(g, cfg.sim.model.radius, compiled=True)
    slow = GridPlanner(g, cfg.sim.model.radius)
    rng = np.random.default_rng(seed)
    free_iy, free_ix = np.nonzero(~footprint)
    pick = rng.choice(free_iy.size, 16)
    pts = list(
        zip(
            (g.origin_x + (free_ix[pick] + 0.5) * g.resolution).tolist(),
            (g.origin_y + (free_iy[pick] + 0.5) * g.resolution).tolist(),
            strict=True,
        )
    )
    obstacles = [(x, y, 0.3) for x, y in pts[:discs]]
    found = 0
    for a, b in zip(pts[::2], pts[1::2], strict=True):
        for ds in ([], obstacles):
            want = slow.plan_avoiding(a, b, ds)
            got = fast.plan_avoiding(a, b, ds)
            assert (got.path, got.error_code) == (want.path, want.error_code)
            found += len(want.path) > 2
    assert found  # some plans went round shelves: the searches were compared
