"""The traffic manager's oncoming-robot index on a running load test, two ways on the same
state: built anew from every live robot's next path nodes (the code before) and kept from
cycle to cycle (``fleet.traffic.grants.moves_ahead``). Every time a cycle first asks for the
index, both are computed, timed in thread CPU (the figure least moved by other work on a loaded
machine) and compared; the fleet drives on with the kept index. Prints how often the two were
equal (every time, or the script fails) and the CPU each took.

    python bench/bench_oncoming.py --robots 1000 --duration 30
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from fleet.traffic.params import ONCOMING_NODES
from fleet.traffic.state import TrafficState


def built_anew(st: TrafficState) -> dict[tuple[str, str], set[str]]:
    """The index as every cycle built it before it was kept."""
    idx: dict[tuple[str, str], set[str]] = {}
    for o in st.robots.values():
        if not o.alive:
            continue
        seg = o.path[o.cur : o.cur + ONCOMING_NODES]
        for a, b in zip(seg, seg[1:], strict=False):
            idx.setdefault((a, b), set()).add(o.name)
    return idx


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=1000)
    p.add_argument("--duration", type=float, default=30.0, help="simulated seconds (default 30)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)

    from fleet.loadtest.run import run_loadtest
    from fleet.traffic import grants, paths

    kept = grants.moves_ahead
    tot = {"anew": 0.0, "kept": 0.0, "times": 0, "equal": 0}

    def both(st: TrafficState) -> dict[tuple[str, str], set[str]]:
        if st.dir_index is not None:
            return st.dir_index
        t0 = time.thread_time()
        ref = built_anew(st)
        t1 = time.thread_time()
        out = kept(st)
        t2 = time.thread_time()
        tot["anew"] += t1 - t0
        tot["kept"] += t2 - t1
        tot["times"] += 1
        tot["equal"] += int(ref == out)
        return out

    grants.moves_ahead = both
    paths.moves_ahead = both  # type: ignore[attr-defined]
    try:
        with tempfile.TemporaryDirectory(prefix="bench-oncoming-") as tmp:
            res = run_loadtest(args.robots, args.duration, out_dir=Path(tmp), seed=args.seed, dpi=40)
    finally:
        grants.moves_ahead = kept
        paths.moves_ahead = kept  # type: ignore[attr-defined]
    n = max(1, int(tot["times"]))
    d = res.data
    print(
        f"{args.robots} robots, {args.duration:g} simulated s: laps {d['laps_completed']}, collisions "
        f"{d['collisions']}, deadlocks {d['deadlocks']}"
    )
    print(
        f"index asked for in {tot['times']} cycles, equal {tot['equal']} times; thread CPU built anew "
        f"{tot['anew'] * 1e3:.1f} ms ({tot['anew'] / n * 1e6:.0f} us a cycle), kept {tot['kept'] * 1e3:.1f} ms "
        f"({tot['kept'] / n * 1e6:.0f} us a cycle): {tot['anew'] / max(tot['kept'], 1e-9):.1f}x"
    )
    return 0 if tot["equal"] == tot["times"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
