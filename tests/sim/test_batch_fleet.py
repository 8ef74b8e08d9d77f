"""The simulator's one batch read path (``sim.batch``: rows answered from the state arrays)
against per-robot and per-goal snapshots, row by row, through a seeded run of a busy fleet:
every goal kind, preemption, cancels, faults, mislocalization, computations, old, foreign
and unknown ids."""

from __future__ import annotations

import random

import numpy as np
from sim_testworld import make_sim

from fleet.navigation import NavBatch, loop_batch
from fleet.types import (
    BackUp,
    ComputePathToPose,
    DriveOnHeading,
    FollowPath,
    FollowWaypoints,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
)

FREE_SPOTS = [
    (1.0, 1.0),
    (1.5, 3.0),
    (1.0, 6.5),
    (3.0, 6.5),
    (6.0, 6.8),
    (10.5, 6.5),
    (10.5, 1.2),
    (9.0, 3.5),
]
EXACT = ("x", "y", "theta", "battery", "distance_m", "collisions", "charging", "stuck", "localized")
EXACT += ("navigation_ready", "goal_status", "goal_error")


def _goal(rng: random.Random, here: Pose2D) -> object:
    spot = Pose2D(*rng.choice(FREE_SPOTS), rng.uniform(-3.0, 3.0))
    kinds = [
        NavigateToPose(spot),
        NavigateThroughPoses((Pose2D(*rng.choice(FREE_SPOTS), 0.0), spot)),
        FollowWaypoints((spot, Pose2D(*rng.choice(FREE_SPOTS), 1.0))),
        FollowPath((here, Pose2D(here.x + 0.8, here.y, 0.0))),
        Spin(rng.uniform(-2.0, 2.0)),
        BackUp(0.2),
        DriveOnHeading(0.3),
        Wait(rng.uniform(0.2, 2.0)),
        ComputePathToPose(spot),
        NavigateToPose(Pose2D(-5.0, -5.0, 0.0)),  # outside the map: rejected or aborted at once
    ]
    return rng.choice(kinds)


def _assert_same(fast: NavBatch, slow: NavBatch) -> None:
    for name in EXACT:
        a, b = getattr(fast, name), getattr(slow, name)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), (name, a, b)
    assert np.allclose(fast.distance_remaining, slow.distance_remaining, rtol=0.0, atol=1e-9, equal_nan=True)


def test_array_rows_agree_with_snapshots_in_a_busy_fleet() -> None:
    rng = random.Random(7)
    robots = {f"/r{k}": Pose2D(x, y, 0.0) for k, (x, y) in enumerate(FREE_SPOTS)}
    sim = make_sim(robots)
    names = list(robots)
    backends = [sim.backend(ns) for ns in names]
    latest: list[str | None] = [None] * len(names)
    issued: list[str] = []
    compared = 0
    for step in range(900):
        if step % 7 == 0:
            k = rng.randrange(len(names))
            gid = sim.send_goal(names[k], _goal(rng, sim.true_pose(names[k])))
            latest[k] = gid
            issued.append(gid)
        if step % 53 == 0 and issued:
            sim.cancel_goal(rng.choice(issued))
        if step % 97 == 0:
            ns = rng.choice(names)
            sim.set_fault(ns, rng.choice([None, "navigation_down", "localization_lost", "stalled", None]))
        if step % 131 == 0:
            ns = rng.choice(names)
            sim.set_initial_pose(ns, Pose2D(rng.uniform(1, 11), rng.uniform(1, 7), 0.0))
        sim.step()
        if step % 5 == 0:
            ids: list[str | None] = list(latest)
            ids[rng.randrange(len(ids))] = rng.choice(issued) if issued else None  # an older goal
            ids[rng.randrange(len(ids))] = rng.choice([None, "/nobody#3", "/r1#999999", "/r2#x"])
            if issued:  # a goal of another robot in this row
                ids[rng.randrange(len(ids))] = rng.choice(issued)
            _assert_same(sim.query_batch(names, ids), loop_batch(backends, ids))
            compared += 1
    assert compared == 180
    assert len(issued) > 100


def test_goal_table_is_the_latest_goal_rows_of_the_batch() -> None:
    robots = {f"/r{k}": Pose2D(x, y, 0.0) for k, (x, y) in enumerate(FREE_SPOTS[:4])}
    sim = make_sim(robots)
    names = list(robots)
    gids = [sim.send_goal(ns, NavigateToPose(Pose2D(10.5, 6.5, 0.0))) for ns in names]
    for _ in range(40):
        sim.step()
    sim.cancel_goal(gids[1])
    table = sim.goal_table()
    batch = sim.query_batch(names, gids)
    assert np.array_equal(table.status, batch.goal_status)
    assert table.number.tolist() == [int(g.rpartition("#")[2]) for g in gids]
