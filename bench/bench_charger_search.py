"""What finding a charger costs the traffic policy's charger queue, before and after the
bounded search.

Generates the floor of ``fleet loadtest --robots N`` (into a temporary directory), builds its
traffic policy (:func:`fleet.traffic.policy.traffic_from_config`: docks joined, the patrol
loops' flow set) and asks, from ``--requests`` roadmap nodes drawn with ``--seed``, for the
charger a robot standing there would be sent to, with a random half of the chargers taken:

* ``full``: the search of before: a Dijkstra over the whole roadmap from the robot
  (``RoadIndex.costs_from``), then the nearest free charger, refused when it is more than
  ``CHARGE_REACH_M`` farther than the nearest of all chargers;
* ``bounded``: ``RoadIndex.costs_near``, which stops ``CHARGE_REACH_M`` past the nearest
  charger (what the charging errand, ``Errands._free_dock``, uses now).

Prints ms per request for both, the ratio, the nodes of the roadmap, and how many requests
got a different answer (must be 0: the bounded search gives the same choice).

    python bench/bench_charger_search.py --robots 1000
"""

from __future__ import annotations

import argparse
import json
import math
import random
import tempfile
import time

from fleet.loadtest.run import prepare_config
from fleet.traffic.errands import CHARGE_REACH_M
from fleet.traffic.policy import traffic_from_config
from fleet.traffic.roads import RoadIndex


def full(roads: RoadIndex, here: str, chargers: list[str], free: list[str]) -> str | None:
    dist = roads.costs_from(here)
    best = min(free, key=lambda d: (dist.get(d, math.inf), d))
    if dist.get(best, math.inf) > min(dist.get(d, math.inf) for d in chargers) + CHARGE_REACH_M:
        return None
    return best


def bounded(roads: RoadIndex, here: str, chargers: list[str], free: set[str]) -> str | None:
    near = roads.costs_near(here, chargers, CHARGE_REACH_M)
    ok = [(c, d) for d, c in near.items() if d in free]
    return min(ok)[1] if ok else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true", help="one JSON line instead of the text")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as out:
        cfg = prepare_config(args.robots, out)
    policy = traffic_from_config(cfg)
    roads = policy.manager._st.roads
    chargers = list(policy.chargers)
    rng = random.Random(args.seed)
    nodes = sorted(roads.pos)
    asks = [rng.choice(nodes) for _ in range(args.requests)]
    frees = [sorted(rng.sample(chargers, max(1, len(chargers) // 2))) for _ in asks]
    t0 = time.perf_counter()
    old = [full(roads, a, chargers, f) for a, f in zip(asks, frees, strict=True)]
    t1 = time.perf_counter()
    new = [bounded(roads, a, chargers, set(f)) for a, f in zip(asks, frees, strict=True)]
    t2 = time.perf_counter()
    res = {
        "robots": args.robots,
        "nodes": len(nodes),
        "chargers": len(chargers),
        "requests": len(asks),
        "full_ms": 1000 * (t1 - t0) / len(asks),
        "bounded_ms": 1000 * (t2 - t1) / len(asks),
        "ratio": (t1 - t0) / max(1e-12, t2 - t1),
        "different": sum(1 for a, b in zip(old, new, strict=True) if a != b),
        "refused": sum(1 for a in old if a is None),
    }
    if args.json:
        print(json.dumps(res))
        return
    print(
        f"{res['robots']} robots: {res['nodes']} roadmap nodes, {res['chargers']} chargers, "
        f"{res['requests']} requests (half the chargers taken, {res['refused']} refused)"
    )
    print(f"  full Dijkstra per request: {res['full_ms']:.2f} ms")
    print(f"  bounded search:            {res['bounded_ms']:.3f} ms  ({res['ratio']:.0f}x faster)")
    print(f"  different choices: {res['different']}")


if __name__ == "__main__":
    main()
