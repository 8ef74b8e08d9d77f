"""The traffic manager's searches at load-test scale, before and after, in one run.

    python bench/bench_traffic_scale.py --robots 2000

On `fleet loadtest`'s generated floor for N robots (traffic roadmap with docks, the patrol
loops' flow) it times, in this one process, each replaced search against the code it
replaced (kept as the ``*_reference`` methods), on the same inputs, and checks that both give
the same answer:

* ``costs_from``: the whole-roadmap costs from a node (the charger queue asks them for every
  robot that needs a charger, every cycle): the Python Dijkstra, the compiled row, and the
  kept row asked again;
* ``shortest`` of the robots joining their patrol loops (A* from each robot's start dock to
  its loop's first waypoint with the flow, the traffic policy's first cycle): the Python A*
  against :meth:`RoadIndex.shortest` (compiled for long searches).

Prints process CPU seconds per side, the ratio and the share of equal answers (must be 1).
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")


def _cpu(f: Callable[[], T]) -> tuple[float, T]:
    """``f()`` and the process CPU seconds it took."""
    c = time.process_time()
    out = f()
    return time.process_time() - c, out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=2000)
    p.add_argument("--sources", type=int, default=40, help="costs_from sources (parking docks)")
    p.add_argument("--joins", type=int, default=400, help="robots whose loop join is searched")
    p.add_argument("--out", type=Path, default=Path("out/bench_traffic_scale"))
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)

    from fleet.loadtest.run import prepare_config
    from fleet.traffic.policy import traffic_from_config

    c0 = time.process_time()
    cfg = prepare_config(a.robots, a.out / f"n{a.robots}")
    policy = traffic_from_config(cfg)
    roads = policy.manager._st.roads
    print(
        f"{a.robots} robots: roadmap {len(roads.pos)} nodes, set-up {time.process_time() - c0:.1f} CPU s",
        file=sys.stderr,
        flush=True,
    )
    rng = random.Random(1)
    rows: dict[str, dict[str, float]] = {}
    # once per process, not per call: the compiled kernels loaded, the directed rows built
    warm = sorted(roads.pos)
    roads.costs_from(warm[0])
    roads._shortest_compiled(warm[0], warm[-1], float("inf"))

    srcs = rng.sample(policy.parking, min(a.sources, len(policy.parking)))
    t_ref, ref = _cpu(lambda: [roads.costs_from_reference(s) for s in srcs])
    roads._rows.clear()
    t_new, new = _cpu(lambda: [roads.costs_from(s) for s in srcs])
    t_kept, _ = _cpu(lambda: [roads.costs_from(s) for s in srcs])
    same = sum(dict(n.items()) == r for n, r in zip(new, ref, strict=True))
    rows["costs_from"] = {
        "calls": len(srcs),
        "before": t_ref,
        "after": t_new,
        "kept": t_kept,
        "same": same / len(srcs),
    }

    names = {r.name: r for r in cfg.robots}
    starts = {n: roads.nearest_node(r.start.x, r.start.y) for n, r in names.items()}
    legs = []
    for route in rng.sample(cfg.routes, min(a.joins, len(cfg.routes))):
        first = next((n for n in route.node_names if n is not None), None)
        if first is not None:
            legs.append((starts[rng.choice(list(names))], str(first)))
    t_ref, ref_p = _cpu(lambda: [roads.shortest_reference(x, y, frozenset()) for x, y in legs])
    roads._heur.clear()
    t_new, new_p = _cpu(lambda: [roads.shortest(x, y, frozenset()) for x, y in legs])
    same = sum(x == y for x, y in zip(new_p, ref_p, strict=True))
    rows["loop_joins"] = {
        "calls": len(legs),
        "before": t_ref,
        "after": t_new,
        "same": same / max(1, len(legs)),
    }

    print(f"{'search':<12} | calls | before CPU s | after CPU s | ratio | same answers")
    for k, r in rows.items():
        ratio = r["before"] / max(r["after"], 1e-9)
        extra = f" (kept rows: {r['kept']:.3f} s)" if "kept" in r else ""
        print(
            f"{k:<12} | {r['calls']:.0f} | {r['before']:.3f} | {r['after']:.3f}{extra} | {ratio:.1f}x | {r['same']:.0%}"
        )
    if a.json:
        print(json.dumps({"robots": a.robots, "nodes": len(roads.pos), **rows}))
    return 0 if all(r["same"] == 1.0 for r in rows.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
