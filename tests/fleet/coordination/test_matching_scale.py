"""The set-up steps of big fleets give the decisions of the plain code they replaced: the
greedy matching without sorting the whole matrix, the charger choice remembered per work and
made in one array pass, the on-charger test from buckets."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.coordination.matching import (
    ON_CHARGER_M,
    SHARE_PENALTY_M,
    ChargerAllocation,
    greedy_match,
    travel_costs,
)
from fleet.coordination.tasks import FloatMatrix, IndexMatrix
from fleet.coordination.views import Observation, RobotView
from fleet.roadmap.distances import Distances
from fleet.roadmap.graph import Roadmap
from fleet.types import Mode, Pose2D


def _travel_costs_rows(
    distances: Distances,
    poses: Sequence[Pose2D],
    entry_idx: IndexMatrix,
    entry_off: FloatMatrix,
    offsets: bool = True,
) -> tuple[FloatMatrix, IndexMatrix]:
    """The reference of :func:`~fleet.coordination.matching.travel_costs`, the code it
    replaced: every padded entry of every task priced per robot (same arguments, same
    results)."""
    roadmap = distances.roadmap
    n_tasks = entry_idx.shape[0]
    costs = np.full((len(poses), n_tasks), np.inf)
    entry = np.zeros((len(poses), n_tasks), dtype=np.int64)
    cols = np.arange(n_tasks)
    for i, pose in enumerate(poses):
        start = roadmap.nearest_node(pose.x, pose.y)
        sx, sy = roadmap.pos(start)
        d = distances.row(start)[entry_idx]
        snap = math.hypot(sx - pose.x, sy - pose.y)
        if offsets:
            k = np.argmin(d + entry_off, axis=1)
            costs[i] = snap + d[cols, k] + entry_off[cols, k]
        else:
            k = np.argmin(d, axis=1)
            costs[i] = snap + d[cols, k]
        entry[i] = k
    return costs, entry


def _greedy_match_sorted(ranks: FloatMatrix) -> list[tuple[int, int]]:
    """The reference of :func:`~fleet.coordination.matching.greedy_match` (the code it
    replaced): a stable sort of every entry, then one pass."""
    n_rows, n_cols = ranks.shape
    pairs: list[tuple[int, int]] = []
    used_r: set[int] = set()
    used_c: set[int] = set()
    n = min(n_rows, n_cols)
    if n == 0:
        return pairs
    for f in np.argsort(ranks, axis=None, kind="stable"):
        i, j = divmod(int(f), n_cols)
        if i in used_r or j in used_c or not math.isfinite(ranks[i, j]):
            continue
        used_r.add(i)
        used_c.add(j)
        pairs.append((i, j))
        if len(pairs) == n:
            break
    return pairs


@settings(max_examples=300, deadline=None)
@given(
    rows=st.integers(0, 14),
    cols=st.integers(0, 14),
    levels=st.integers(1, 6),
    inf_share=st.floats(0.0, 0.6),
    seed=st.integers(0, 2**31 - 1),
)
def test_greedy_match_equals_the_whole_sorted_matrix(
    rows: int, cols: int, levels: int, inf_share: float, seed: int
) -> None:
    """Few distinct ranks (many ties, also at a row's last offered column), unreachable
    entries, more rows than columns and the other way round: the same pairs in the same order."""
    rng = np.random.default_rng(seed)
    ranks = rng.integers(0, levels, size=(rows, cols)).astype(float)
    ranks[rng.random((rows, cols)) < inf_share] = math.inf
    if rows and cols and seed % 3 == 0:
        ranks[rng.integers(0, rows), rng.integers(0, cols)] = -1e9  # a preferred robot
    assert greedy_match(ranks) == _greedy_match_sorted(ranks)


def test_greedy_match_equals_the_sorted_matrix_on_a_fleet_sized_one() -> None:
    """400 robots x 400 tasks of real-looking costs (route copies: identical columns)."""
    rng = np.random.default_rng(7)
    base = rng.uniform(0, 300, size=(400, 40)).round(1)
    ranks = np.repeat(base, 10, axis=1)  # 40 loops, 10 copies each
    ranks[rng.random(ranks.shape) < 0.01] = math.inf
    assert greedy_match(ranks) == _greedy_match_sorted(ranks)


def _grid_roadmap(n: int) -> Roadmap:
    nodes = {f"n{i}_{j}": [10.0 * i, 7.0 * j] for i in range(n) for j in range(3)}
    edges = [[f"n{i}_{j}", f"n{i + 1}_{j}"] for i in range(n - 1) for j in range(3)]
    edges += [[f"n{i}_{j}", f"n{i}_{j + 1}"] for i in range(n) for j in range(2)]
    return Roadmap.from_config_dict({"nodes": nodes, "edges": edges})


def _view(name: str, x: float, y: float) -> RobotView:
    v = RobotView(name=name, last_seen=0.0, progress_t=0.0)
    v.obs = Observation(t=0.0, pose=Pose2D(x, y, 0.0), mode=Mode.IDLE, battery=1.0)
    return v


def _reference_choice(alloc: ChargerAllocation, d: Distances, v: RobotView, work: tuple[str, ...]) -> int:
    """The charger the plain code chose: a mean of roadmap rows, then ``min`` over Python floats."""
    if work:
        sources = [n for n in work if n in d.index]
    else:
        assert v.obs is not None and v.obs.pose is not None
        sources = [d.roadmap.nearest_node(v.obs.pose.x, v.obs.pose.y)]
    total = np.zeros(len(alloc.columns))
    for n in sources:
        total += d.row(n)[alloc.columns]
    dist = [float(x) for x in np.nan_to_num(total / len(sources), posinf=1e9)]
    return min(range(len(alloc.poses)), key=lambda i: (dist[i] + SHARE_PENALTY_M * alloc.load[i], i))


def test_charger_choice_equals_the_plain_computation() -> None:
    """Robots sharing works (route copies) and robots without work, chargers tied at equal
    distance: each robot gets the charger the plain computation names, load included."""
    rm = _grid_roadmap(30)
    d = Distances(rm)
    chargers = [Pose2D(10.0 * i, y, 0.0) for i in range(0, 30, 3) for y in (0.0, 14.0)]
    alloc = ChargerAllocation(chargers, d)
    rng = np.random.default_rng(3)
    works = [tuple(f"n{i}_{j}" for i in range(a, a + 4) for j in (0, 2)) for a in range(0, 26, 5)]
    for k in range(120):
        v = _view(f"r{k}", float(rng.uniform(0, 290)), float(rng.choice([0.0, 7.0, 14.0])))
        work = works[k % len(works)] if k % 4 else ()
        want = _reference_choice(alloc, d, v, work)
        assert alloc.charger_for(v, work) == chargers[want]
        assert v.charger == want


@settings(max_examples=200, deadline=None)
@given(
    dx=st.floats(-2 * ON_CHARGER_M, 2 * ON_CHARGER_M),
    dy=st.floats(-2 * ON_CHARGER_M, 2 * ON_CHARGER_M),
    k=st.integers(0, 5),
)
def test_on_charger_equals_testing_every_charger(dx: float, dy: float, k: int) -> None:
    """At, around and across the :data:`ON_CHARGER_M` radius, also across bucket edges."""
    chargers = [Pose2D(0.25 + 1.5 * i, -0.5 * i, 0.0) for i in range(6)]
    alloc = ChargerAllocation(chargers)
    c = chargers[k]
    v = _view("r", c.x + dx, c.y + dy)
    assert v.obs is not None and v.obs.pose is not None
    pose = v.obs.pose
    assert alloc.on_charger(v) == any(pose.distance_to(q) <= ON_CHARGER_M for q in chargers)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), radius=st.sampled_from([0.05, 0.25, 0.3, 0.45, 1.0]))
def test_free_at_equals_is_free_point_by_point(seed: int, radius: float) -> None:
    """On the shipped warehouse map, at random points on and off the map and near walls."""
    from pathlib import Path

    from fleet.maps import load_map

    grid = load_map(Path(__file__).parents[3] / "configs" / "maps" / "warehouse.yaml")
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = grid.extent
    xs = rng.uniform(xmin - 1.0, xmax + 1.0, 400)
    ys = rng.uniform(ymin - 1.0, ymax + 1.0, 400)
    got = grid.free_at(xs, ys, radius)
    assert got.tolist() == [grid.is_free(float(x), float(y), radius) for x, y in zip(xs, ys, strict=True)]


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_nearest_charger_equals_min_over_the_chargers(seed: int) -> None:
    """On a lattice (many ties in ``|dx| + |dy|``, also on ``x``), and with duplicate poses."""
    from fleet.runtime.charger_index import nearest_charger

    rng = np.random.default_rng(seed)
    chargers = tuple(
        Pose2D(float(x), float(y), float(t))
        for x, y, t in zip(
            rng.integers(0, 6, 30), rng.integers(0, 4, 30), rng.integers(0, 3, 30), strict=True
        )
    )
    for _ in range(30):
        pose = Pose2D(float(rng.integers(-2, 8)) / 2, float(rng.integers(-2, 6)) / 2, 0.0)
        want = min(chargers, key=lambda c: (abs(c.x - pose.x) + abs(c.y - pose.y), c.x, c.y))
        assert nearest_charger(chargers, pose) is want


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), offsets=st.booleans())
def test_travel_costs_equal_the_padded_rows(seed: int, offsets: bool) -> None:
    """Route copies (equal rows), padded rows of several widths, ties between entries,
    unreachable nodes: the same costs and entries, float for float."""
    rm = _grid_roadmap(12)
    island = Roadmap.from_config_dict(
        {
            "nodes": {**{n: list(rm.pos(n)) for n in rm.nodes}, "far": [500.0, 500.0]},
            "edges": [[a, b] for a, b in rm.graph.edges],
        }
    )
    d = Distances(island)
    rng = np.random.default_rng(seed)
    n_nodes = len(d.names)
    rows = []
    for _ in range(int(rng.integers(1, 9))):
        k = int(rng.integers(1, 7))
        idx = rng.integers(0, n_nodes, k)
        off = rng.choice([0.0, 0.5, 1.0], k) if offsets else np.zeros(k)
        for _ in range(int(rng.integers(1, 4))):  # copies
            rows.append((idx, off))
    width = max(len(i) for i, _ in rows)
    m = np.zeros((len(rows), width), dtype=np.int64)
    o = np.zeros((len(rows), width))
    for r, (idx, off) in enumerate(rows):
        m[r, :], o[r, :] = idx[-1], off[-1]
        m[r, : len(idx)], o[r, : len(off)] = idx, off
    poses = [Pose2D(float(x), float(y), 0.0) for x, y in rng.uniform(-5, 120, (6, 2))]
    c1, e1 = travel_costs(d, poses, m, o, offsets)
    c2, e2 = _travel_costs_rows(d, poses, m, o, offsets)
    assert np.array_equal(c1, c2) and np.array_equal(e1, e2)
