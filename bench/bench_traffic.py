"""Milliseconds per traffic-manager cycle with many robots (``fleet.traffic.TrafficManager``).

N robots on a square grid roadmap (2 m edges, about 1.6 nodes per robot), each given a
shortest path to a random node; every simulated 0.1 s one in ten robots is moved half way to
its next granted node (teleported, no simulator), every robot's pose is fed in with
``update`` and one ``cycle`` is timed. Only ``cycle`` is timed; the seed fixes the workload,
so two code versions can be compared on the same machine in one session.

    python bench/bench_traffic.py                        # 1000 robots, 200 cycles, 3 repeats
    python bench/bench_traffic.py --robots 5000 --side 90
    python bench/bench_traffic.py --json                 # one JSON line

Prints the median, p95 and max cycle (ms) of each repeat and the best median; spikes of
tens of ms are usually Python's cyclic garbage collector (``--no-gc`` shows it). On a
shared machine ``--cpu`` (this process's CPU time) is steadier than the wall clock.
"""

from __future__ import annotations

import argparse
import gc
import json
import random
import statistics
import sys
import time
from collections.abc import Callable

import networkx as nx

from fleet.roadmap.graph import Roadmap
from fleet.traffic.manager import TrafficManager
from fleet.types import Pose2D


def grid_roadmap(side: int, spacing: float) -> Roadmap:
    """A ``side`` x ``side`` grid roadmap, nodes ``n<i>_<j>``, ``spacing`` m apart."""
    g = nx.Graph()
    for i in range(side):
        for j in range(side):
            g.add_node(f"n{i}_{j}", pos=(i * spacing, j * spacing))
    for i in range(side):
        for j in range(side):
            if i + 1 < side:
                g.add_edge(f"n{i}_{j}", f"n{i + 1}_{j}")
            if j + 1 < side:
                g.add_edge(f"n{i}_{j}", f"n{i}_{j + 1}")
    return Roadmap.from_graph(g)


def run(
    robots: int, side: int, cycles: int, seed: int, clock: Callable[[], float] = time.perf_counter
) -> list[float]:
    """Seconds of every timed ``cycle`` of one seeded run, read on ``clock``."""
    rm = grid_roadmap(side, 2.0)
    rng = random.Random(seed)
    tm = TrafficManager(rm)
    pos: dict[str, Pose2D] = {}
    for i, s in enumerate(rng.sample(rm.nodes, robots)):
        x, y = rm.pos(s)
        name = f"r{i}"
        pos[name] = Pose2D(x, y)
        tm.add_robot(name, pos[name], 0.0)
        tm.set_path(name, rm.shortest_path(s, rng.choice(rm.nodes)) or [s], 0.0)
    times: list[float] = []
    now = 0.0
    for _ in range(cycles):
        now += 0.1
        for name, p in pos.items():
            gr = tm.grant(name) if rng.random() < 0.1 else None
            if gr is not None and gr.nodes:
                tx, ty = rm.pos(gr.nodes[0])
                pos[name] = Pose2D(p.x + 0.5 * (tx - p.x), p.y + 0.5 * (ty - p.y))
            tm.update(name, pos[name], now)
        t0 = clock()
        tm.cycle(now)
        times.append(clock() - t0)
    return times


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=1000, help="robots (default 1000)")
    ap.add_argument("--side", type=int, default=40, help="grid roadmap side in nodes (default 40)")
    ap.add_argument("--cycles", type=int, default=200, help="timed cycles per repeat (default 200)")
    ap.add_argument("--repeat", type=int, default=3, help="repeats of the seeded run (default 3)")
    ap.add_argument("--seed", type=int, default=5, help="workload seed (default 5)")
    ap.add_argument("--no-gc", action="store_true", help="disable Python's cyclic garbage collector")
    ap.add_argument(
        "--cpu",
        action="store_true",
        help="time on this process's CPU clock instead of the wall clock (steadier on a shared machine)",
    )
    ap.add_argument("--json", action="store_true", help="print one JSON line instead of the table")
    ap.add_argument("--quick", action="store_true", help="small run for make bench (300 robots)")
    args = ap.parse_args(argv)
    if args.quick:
        args.robots, args.side, args.cycles, args.repeat = 300, 22, 100, 1
    if args.robots > args.side * args.side:
        ap.error(f"--robots {args.robots} exceeds the {args.side * args.side} roadmap nodes")
    if args.no_gc:
        gc.disable()
    medians: list[float] = []
    rows = []
    for k in range(args.repeat):
        clock = time.process_time if args.cpu else time.perf_counter
        ts = sorted(run(args.robots, args.side, args.cycles, args.seed, clock))
        med = statistics.median(ts)
        medians.append(med)
        row = {
            "repeat": k + 1,
            "median_ms": round(1000 * med, 3),
            "p95_ms": round(1000 * ts[int(0.95 * (len(ts) - 1))], 3),
            "max_ms": round(1000 * ts[-1], 3),
        }
        rows.append(row)
        if not args.json:
            print(
                f"{args.robots} robots, {args.side}x{args.side} nodes, repeat {k + 1}: median "
                f"{row['median_ms']:.2f} ms, p95 {row['p95_ms']:.2f} ms, max {row['max_ms']:.2f} ms",
                flush=True,
            )
    best = round(1000 * min(medians), 3)
    if args.json:
        print(json.dumps({"robots": args.robots, "side": args.side, "best_median_ms": best, "repeats": rows}))
    else:
        print(f"best median: {best:.2f} ms per cycle")
    return 0


if __name__ == "__main__":
    sys.exit(main())
