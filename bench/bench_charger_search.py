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
  charger (what the charging errand, ``Errands._free_dock``, uses now), compiled;
* ``bounded, Python``: the same search in Python (``costs_near_reference``, what it was
  before the compiled kernel);
* ``nearest``: the nearest free charger by ``RoadIndex.nearest`` (the queue's other search),
  compiled and in Python (``nearest_reference``).

Prints ms per request for each, the ratios, the nodes of the roadmap, and how many requests
got a different answer (must be 0: every search gives the same choice).

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


def bounded(
    roads: RoadIndex, here: str, chargers: list[str], free: set[str], python: bool = False
) -> str | None:
    search = roads.costs_near_reference if python else roads.costs_near
    near = search(here, chargers, CHARGE_REACH_M)
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
    roads.costs_near(asks[0], chargers, CHARGE_REACH_M)  # load the compiled kernels first
    roads.nearest(asks[0], chargers)
    t0 = time.perf_counter()
    old = [full(roads, a, chargers, f) for a, f in zip(asks, frees, strict=True)]
    t1 = time.perf_counter()
    new = [bounded(roads, a, chargers, set(f)) for a, f in zip(asks, frees, strict=True)]
    t2 = time.perf_counter()
    py = [bounded(roads, a, chargers, set(f), python=True) for a, f in zip(asks, frees, strict=True)]
    t3 = time.perf_counter()
    near_c = [roads.nearest(a, f) for a, f in zip(asks, frees, strict=True)]
    t4 = time.perf_counter()
    near_py = [roads.nearest_reference(a, f) for a, f in zip(asks, frees, strict=True)]
    t5 = time.perf_counter()
    res = {
        "robots": args.robots,
        "nodes": len(nodes),
        "chargers": len(chargers),
        "requests": len(asks),
        "full_ms": 1000 * (t1 - t0) / len(asks),
        "bounded_ms": 1000 * (t2 - t1) / len(asks),
        "ratio": (t1 - t0) / max(1e-12, t2 - t1),
        "bounded_python_ms": 1000 * (t3 - t2) / len(asks),
        "compiled_ratio": (t3 - t2) / max(1e-12, t2 - t1),
        "nearest_ms": 1000 * (t4 - t3) / len(asks),
        "nearest_python_ms": 1000 * (t5 - t4) / len(asks),
        "nearest_ratio": (t5 - t4) / max(1e-12, t4 - t3),
        "different": sum(1 for a, b in zip(old, new, strict=True) if a != b),
        "different_python": sum(1 for a, b in zip(py, new, strict=True) if a != b),
        "different_nearest": sum(1 for a, b in zip(near_py, near_c, strict=True) if a != b),
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
    print(
        f"  bounded search in Python:  {res['bounded_python_ms']:.3f} ms  "
        f"(compiled {res['compiled_ratio']:.1f}x faster)"
    )
    print(
        f"  nearest free charger: {res['nearest_ms']:.3f} ms compiled, {res['nearest_python_ms']:.3f} ms "
        f"in Python ({res['nearest_ratio']:.1f}x)"
    )
    print(
        f"  different choices: {res['different']} (bounded vs full), {res['different_python']} "
        f"(compiled vs Python), {res['different_nearest']} (nearest)"
    )


if __name__ == "__main__":
    main()
