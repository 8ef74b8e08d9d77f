"""The kinematic simulator and SUMO side by side: robot-steps per second on the same
generated warehouse, the same robots, the same step length and the same number of steps.

Both sides load ``fleet.warehouse.generate_warehouse(tmp, "bench", N)`` through
``fleet.config.load_config(path, robots=N)`` and use its robots (names, start poses) and robot
model, with ``step_s`` (default 0.05 s) on both sides, and time ``K`` steps after an untimed
warm-up. What each side computes per step:

* **sim** (``bench/bench_sim.py``): ``Simulator.step()`` over the occupancy map: every robot's
  path follower, local avoidance, reactive safety stop, static-obstacle clamping, battery,
  progress checker and contact counting. Robot ``i`` patrols route ``i mod R`` of the config
  (NavigateThroughPoses of ``config.route_poses(route)``, re-sent when it ends); goals are
  polled at 10 Hz of simulated time inside the timed loop, every robot's state and goal in one
  ``Simulator.query_batch()`` call (the navigation contract's batch query).
* **SUMO** (``bench/sumo_steps.py``, ``sim/sumo/world.py``): the warehouse roadmap converted
  to a SUMO network, one vehicle per robot, ``libsumo.simulationStep()`` plus the backend's
  per-step bookkeeping (positions of every vehicle, arrivals, collisions, teleports). Robot
  ``i`` patrols the same route as on the simulator's side (NavigateThroughPoses of
  ``config.route_poses(route i mod R)``, snapped to lanes and routed by SUMO), re-sent when it
  ends, polled at 10 Hz of simulated time inside the timed loop, every goal's status in one
  call of the world's goal book (``GoalBook.status_codes``). (Until this change SUMO's robots
  drove NavigateThroughPoses through random roadmap nodes, each goal's poses found by
  networkx shortest paths: at 10,000 robots that and snapping every pose by a scan of every
  lane kept SUMO's set-up from finishing in 30 minutes.)

The simulator runs again after SUMO on the same world and the ratio uses the mean of its two
runs: on a shared machine the load drifts while SUMO sets up and runs (minutes at 5000 robots),
and the mean of the runs before and after sees about what SUMO saw.

Command line::

    python bench/sim_vs_sumo.py --robots 1000 --steps 400
    python bench/sim_vs_sumo.py --robots 1000 5000 10000 --steps 200   # the issue's three sizes
    python bench/sim_vs_sumo.py --robots 30 --steps 2000 --json
    python bench/sim_vs_sumo.py --robots 1000 5000 --steps 200 --cpu-time   # CPU s, not wall s

``--cpu-time`` times both sides in CPU seconds of this process (libsumo runs inside it): on a
machine shared with other jobs the wall time of either side is mostly waiting for a core, and
how much moves from minute to minute (SUMO's 1000-robot step took 9.9-38.9 ms of wall time in
three runs within 20 minutes, 3.5 ms of CPU).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_sim import describe, load_world, run_sim_steps  # noqa: E402


def compare(n_robots: int, steps: int, step_s: float) -> dict[str, object]:
    """One size: the simulator's side, then SUMO's, on the same generated warehouse; prints
    both lines and returns the figures."""
    out = Path(tempfile.mkdtemp(prefix="sim_vs_sumo_"))
    cfg = load_world(n_robots, out)
    sim_res = run_sim_steps(cfg, steps, step_s=step_s)
    print(describe(sim_res), flush=True)
    from sumo_steps import run_sumo_steps

    sumo_res = run_sumo_steps(
        n_robots,
        steps,
        roadmap=cfg.roadmap,
        robots=list(cfg.robots),
        params=replace(cfg.sim, step_s=step_s),
        cache_dir=out / "sumo",
        routes=[cfg.route_poses(r) for r in cfg.routes],
    )
    print(
        f"SUMO: {sumo_res.robots} robots x {sumo_res.steps} steps of {sumo_res.step_s:g} s on the same "
        f"warehouse roadmap ({sumo_res.junctions} junctions, {sumo_res.lanes} lanes): "
        f"{sumo_res.robot_steps_per_s:,.0f} robot-steps/s "
        f"({sumo_res.step_wall_s / sumo_res.steps * 1000:.2f} ms/step, {sumo_res.real_time_factor:.1f}x real time; "
        f"setup {sumo_res.setup_wall_s:.1f} s; goals ok {sumo_res.goals_succeeded}, failed "
        f"{sumo_res.goals_failed}; collisions {sumo_res.collisions}, teleports {sumo_res.teleports})",
        flush=True,
    )
    # the simulator again after SUMO: the machine's load drifts over a run, and the mean of
    # the runs before and after SUMO sees about the load SUMO saw
    sim_after = run_sim_steps(cfg, steps, step_s=step_s)
    print("again " + describe(sim_after), flush=True)
    rate = (sim_res.robot_steps_per_s + sim_after.robot_steps_per_s) / 2
    rate_step = (sim_res.step_only_robot_steps_per_s + sim_after.step_only_robot_steps_per_s) / 2
    ratio = rate / sumo_res.robot_steps_per_s
    ratio_step = rate_step / sumo_res.robot_steps_per_s
    print(
        f"ratio sim / SUMO at {n_robots} robots: {ratio:.1f}x (with goal polling on both sides; the simulator's "
        f"mean of the runs before and after SUMO); Simulator.step() alone vs SUMO: {ratio_step:.1f}x",
        flush=True,
    )
    return {
        "sim": asdict(sim_res),
        "sim_after": asdict(sim_after),
        "sumo": asdict(sumo_res),
        "ratio": ratio,
        "ratio_step_only": ratio_step,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="Robot-steps/s of the kinematic simulator and of SUMO (libsumo) on the same "
        "generated warehouse roadmap, robot count, step length and step count, for each size.",
        epilog="Example: python bench/sim_vs_sumo.py --robots 1000 5000 10000 --steps 200",
    )
    ap.add_argument(
        "--robots",
        "-n",
        type=int,
        nargs="+",
        default=[1000],
        help="robot counts, one comparison each (default 1000)",
    )
    ap.add_argument("--steps", "-k", type=int, default=400, help="steps to time on each side (default 400)")
    ap.add_argument(
        "--step-s", type=float, default=0.05, help="step length in s on both sides (default 0.05)"
    )
    ap.add_argument("--json", action="store_true", help="print every result and ratio as JSON at the end")
    ap.add_argument(
        "--cpu-time",
        action="store_true",
        help="time both sides in this process's CPU seconds instead of wall seconds (both run in this "
        "process): on a shared machine wall time is mostly waiting for a core",
    )
    args = ap.parse_args(argv)
    if args.cpu_time:
        # bench_sim and sumo_steps read time.perf_counter at each call
        time.perf_counter = time.process_time
    results = [compare(n, args.steps, args.step_s) for n in args.robots]
    print(
        "\n| robots | sim robot-steps/s (with polling), before / after SUMO | sim step only | "
        "SUMO robot-steps/s | ratio | ratio, step only |"
    )
    print("|---|---|---|---|---|---|")
    for n, r in zip(args.robots, results, strict=True):
        sim_r, sim_a, sumo_r = r["sim"], r["sim_after"], r["sumo"]
        assert isinstance(sim_r, dict) and isinstance(sim_a, dict) and isinstance(sumo_r, dict)
        print(
            f"| {n} | {sim_r['robot_steps_per_s']:,.0f} / {sim_a['robot_steps_per_s']:,.0f} | "
            f"{sim_r['step_only_robot_steps_per_s']:,.0f} / {sim_a['step_only_robot_steps_per_s']:,.0f} | "
            f"{sumo_r['robot_steps_per_s']:,.0f} | {r['ratio']:.1f}x | {r['ratio_step_only']:.1f}x |"
        )
    if args.json:
        print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
