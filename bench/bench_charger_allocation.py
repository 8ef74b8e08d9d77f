"""How far from its work each robot's named charger is, on a load test's generated floor.

Generates the floor of ``fleet loadtest --robots N`` (into a temporary directory), replays the
coordinator's charger allocation (:class:`fleet.coordination.matching.ChargerAllocation`) over
the floor's patrol loops, one robot per loop in config order, and prints the roadmap travel
distance (m, mean over the loop's nodes) from each loop to its robot's named charger: mean and
max, the same for the nearest charger, and the most robots named to one charger. ``--straight``
replays the allocation of before (least-loaded charger first, nearest by straight line from the
robot's start pose) for comparison. Deterministic (seed 1).

    python bench/bench_charger_allocation.py --robots 100
    python bench/bench_charger_allocation.py --robots 1000 --straight
"""

from __future__ import annotations

import argparse
import json
import tempfile

import numpy as np

from fleet.coordination.matching import SHARE_PENALTY_M
from fleet.coordination.state import state_from_config
from fleet.coordination.views import Observation, RobotView
from fleet.loadtest.run import prepare_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument(
        "--straight", action="store_true", help="also replay the straight-line, least-loaded rule"
    )
    ap.add_argument("--json", action="store_true", help="one JSON line instead of the text")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as out:
        cfg = prepare_config(args.robots, out)
    st = state_from_config(cfg)
    alloc, dist = st.chargers, st.book.distances
    routes = list(st.routes.values())[: args.robots]
    starts = [r.start for r in cfg.robots]

    def loop_to(route_nodes: tuple[str, ...], charger: int) -> float:
        col = alloc.columns[charger]
        return float(np.mean([dist.row(n)[col] for n in route_nodes]))

    named, nearest, straight = [], [], []
    load = [0] * len(alloc.poses)
    for i, r in enumerate(routes):
        v = RobotView(f"r{i}", obs=Observation(t=0.0, pose=r.poses[0]))
        alloc.charger_for(v, list(r.nodes))
        assert v.charger is not None
        named.append(loop_to(r.nodes, v.charger))
        nearest.append(min(loop_to(r.nodes, c) for c in range(len(alloc.poses))))
        if args.straight:
            p = starts[i % len(starts)]
            k = min(range(len(alloc.poses)), key=lambda j: (load[j], p.distance_to(alloc.poses[j]), j))
            load[k] += 1
            straight.append(loop_to(r.nodes, k))
    if args.json:
        out = {"robots": args.robots, "chargers": len(alloc.poses), "named_mean_m": float(np.mean(named))}
        out |= {
            "named_max_m": max(named),
            "nearest_mean_m": float(np.mean(nearest)),
            "max_load": max(alloc.load),
        }
        if straight:
            out |= {"before_mean_m": float(np.mean(straight)), "before_max_m": max(straight)}
        print(json.dumps(out))
        return
    print(f"{args.robots} robots, {len(alloc.poses)} chargers, {len(routes)} loops (loop to charger, m)")
    print(
        f"  named (travel distance + {SHARE_PENALTY_M:g} m per robot sharing): mean {np.mean(named):.1f}  max {max(named):.1f}"
    )
    print(
        f"  nearest charger:                               mean {np.mean(nearest):.1f}  max {max(nearest):.1f}"
    )
    print(f"  most robots named to one charger: {max(alloc.load)}")
    if straight:
        print(
            f"  before (least loaded, straight line from the start): mean {np.mean(straight):.1f}  max {max(straight):.1f}"
        )


if __name__ == "__main__":
    main()
