"""Soak: a long run's memory (RSS) over simulated time.

Runs a load-test fleet (generated warehouse, every agent and the coordinator in one process,
traffic management on unless ``--no-traffic``) as fast as it goes and prints the process's RSS
every ``--every`` simulated seconds, then the growth after the warm-up (``--warmup`` share of
the run): the highest RSS after it over the RSS at its end, and the slope (kB per simulated
second). Figures: docs/performance.md ("Soak").

    python bench/soak.py --robots 200 --duration 1800
    python bench/soak.py --robots 200 --duration 3600 --json
    python bench/soak.py --robots 200 --duration 3600 --no-traffic   # a fleet that keeps driving
    make soak                                                        # 8 simulated hours
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fleet.loadtest.soak import DEFAULT_WARMUP, RssSample, run_soak  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=200, help="robots (default 200)")
    p.add_argument("--duration", type=float, default=1800.0, help="simulated seconds (default 1800)")
    p.add_argument("--every", type=float, default=60.0, help="sample RSS every S simulated seconds (60)")
    p.add_argument("--warmup", type=float, default=DEFAULT_WARMUP, help="warm-up share of the run (0.25)")
    p.add_argument("--no-traffic", action="store_true", help="without traffic management")
    p.add_argument("--out", type=Path, help="where the generated warehouse goes (default: a temp dir)")
    p.add_argument("--json", action="store_true", help="also print one JSON line with the result")
    a = p.parse_args(argv)

    def show(s: RssSample) -> None:
        left = f"about {(a.duration - s.t) * s.wall_s / s.t / 60:.1f} min wall left" if s.t > 0 else ""
        print(
            f"t={s.t:7.0f} s sim  {s.wall_s:7.1f} s wall  RSS {s.rss_mb:7.1f} MB  {s.laps:6d} laps  {left}",
            flush=True,
        )

    with tempfile.TemporaryDirectory() as tmp:
        out = a.out or Path(tmp)
        r = run_soak(
            a.robots,
            a.duration,
            out,
            every_s=a.every,
            warmup=a.warmup,
            traffic=not a.no_traffic,
            on_sample=show,
        )
    rep = r.report
    assert rep is not None
    wall = r.samples[-1].wall_s
    print(
        f"{r.robots} robots, {rep.sim_time_s:.0f} s simulated in {wall:.0f} s wall "
        f"({rep.sim_time_s / max(wall, 1e-9):.1f}x real time), traffic {'off' if a.no_traffic else 'on'}, "
        f"{rep.laps_completed} laps, {rep.collisions} collisions"
    )
    print(
        f"RSS: {r.samples[0].rss_mb:.0f} MB at start, {r.baseline_mb:.0f} MB after the warm-up "
        f"({a.warmup:.0%}), max {max(s.rss_mb for s in r.after_warmup()):.0f} MB after it: "
        f"growth {100 * r.growth:.1f} %, slope {r.growth_kb_per_sim_s:.1f} kB per simulated s; "
        f"{r.report_mb:.0f} MB once the report is built"
    )
    if a.json:
        print(
            json.dumps(
                {
                    "robots": r.robots,
                    "sim_s": rep.sim_time_s,
                    "wall_s": wall,
                    "baseline_mb": r.baseline_mb,
                    "growth": r.growth,
                    "slope_kb_per_sim_s": r.growth_kb_per_sim_s,
                    "report_mb": r.report_mb,
                    "samples": [[s.t, s.rss_mb] for s in r.samples],
                }
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
