#!/usr/bin/env python3
"""A SHA-256 digest of a simulator run: to show that a change to the simulator leaves its
results bit-identical (run it against two checkouts and compare the printed digests).

The world is the benchmark warehouse of ``bench/bench_sim.py`` (``generate_warehouse(tmp,
"bench", N)``); robot ``i`` patrols route ``i mod R`` and gets the same goal again when its goal
ends. After every step the digest takes every robot's pose, velocities, battery, odometer,
collision count and charging / stuck flags; every ``--poll`` steps it takes the batch read of
every robot and its goal (``Simulator.query_batch``: poses, goal statuses, error codes and
remaining distances) and every robot's global costmap marks.

Usage: PYTHONPATH=<checkout> python bench/sim_digest.py [--robots 300] [--steps 600] [--poll 2]
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_sim import load_world  # noqa: E402


def digest(n_robots: int, steps: int, poll: int) -> tuple[str, int]:
    """The hex digest of the run and how many goals were sent."""
    from fleet.clock import SimClock
    from fleet.types import NavigateThroughPoses
    from sim.goals import TERMINAL
    from sim.simulator import Simulator

    cfg = load_world(n_robots)
    sim = Simulator(cfg.grid, replace(cfg.sim, step_s=0.05), SimClock())
    for spec in cfg.robots:
        sim.add_robot(spec)
    routes = [cfg.route_poses(r) for r in cfg.routes]
    nss = sim.namespaces
    goals = [sim.send_goal(ns, NavigateThroughPoses(routes[i % len(routes)])) for i, ns in enumerate(nss)]
    sent = len(goals)
    h = hashlib.sha256()
    for k in range(steps):
        sim.step()
        t = sim.robot_table()
        for a in (t.x, t.y, t.theta, t.v, t.w, t.battery, t.distance_m, t.collisions, t.charging, t.stuck):
            h.update(a.tobytes())
        if k % poll == 0:
            b = sim.query_batch(nss, goals)
            for a in (b.x, b.y, b.theta, b.goal_status, b.goal_error, b.distance_remaining, b.localized):
                h.update(a.tobytes())
            for ns in nss:
                for m in sim.costmap_marks(ns):
                    h.update(repr((m.x, m.y, m.r, m.seen, m.source)).encode())
            for i in TERMINAL[b.goal_status].nonzero()[0].tolist():
                goals[i] = sim.send_goal(nss[i], NavigateThroughPoses(routes[i % len(routes)]))
                sent += 1
    return h.hexdigest(), sent


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=300)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--poll", type=int, default=2, help="steps between two batch reads (default 2)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    hexd, sent = digest(args.robots, args.steps, args.poll)
    print(
        f"{args.robots} robots x {args.steps} steps, {sent} goals sent: sha256 {hexd} "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
