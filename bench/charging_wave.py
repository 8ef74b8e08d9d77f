"""Where a load-test fleet's charging robots are, over time (issue 13: the charging wave).

Every ``--every`` simulated seconds it counts the robots whose mode is ``charging`` by the
phase of their charging trip, and the flat ones (battery under 1 %) by mode:

* ``queued``: on the way to a charger leaf, but the traffic policy has given it no charger
  (waiting for one on a parking dock, or not served yet);
* ``to-ch drive`` / ``to-ch held``: given a charger, driving to it / held by the traffic
  manager (waiting for right of way);
* ``on-ch``: the charge leaf, the simulator charging it;
* ``chg-leaf off``: the charge leaf, but not charging (not on a charger);
* ``full``: battery at or above the charge leaf's ``resume`` and still ``charging``;
* ``flat``: battery under 1 % (any mode; also counted in the phase above).

And the free chargers (nobody holds them). Deterministic: same arguments, same run.

    python bench/charging_wave.py --robots 300 --duration 900
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(ROOT))  # run from a checkout; PYTHONPATH chooses another

from fleet.loadtest.run import run_loadtest  # noqa: E402
from fleet.runtime.runner import FleetRunner  # noqa: E402
from fleet.traffic.purpose import Purpose  # noqa: E402

COLS = ("queued", "to-ch drive", "to-ch held", "on-ch", "chg-leaf off", "full", "flat")


class Wave:
    """A runner observer printing one line of counts every ``every`` simulated seconds."""

    def __init__(self, every: float, resume: float) -> None:
        self.every = every
        self.resume = resume
        self.last = -1e9
        self.rows: list[tuple[float, Counter[str]]] = []

    def _named(self, runner: FleetRunner, c: Counter[str]) -> None:
        """Manhattan distance (m) from each robot to its named charger (the battery guard's)."""
        ds = []
        charges = sorted(a.charges for a in runner.agents)
        if charges:
            c["charges p90"], c["charges max"] = charges[int(0.9 * len(charges))], charges[-1]
        for a in runner.agents:
            ch = a.bb.charger if a.bb.exists("charger") else None
            st = a.backend.robot_state() if hasattr(a, "backend") else None
            if ch is None or st is None or st.pose is None:
                continue
            d = abs(ch.x - st.pose.x) + abs(ch.y - st.pose.y)
            if a.last_status is not None and a.last_status.mode == "charging":
                if abs(st.linear_velocity) < 0.05 and not st.charging:
                    c["charging, standing off a charger"] += 1
                if d >= 75.0:
                    c["charging, far named"] += 1
            ds.append(d)
            if d >= 75.0:
                c["far named"] += 1
        ds.sort()
        if ds:
            c["d50"], c["d90"], c["dmax"] = (int(ds[len(ds) // 2]), int(ds[int(0.9 * len(ds))]), int(ds[-1]))

    def __call__(self, now: float, runner: FleetRunner) -> None:
        if now - self.last < self.every:
            return
        self.last = now
        policy = getattr(runner, "traffic_policy", None)
        c: Counter[str] = Counter()
        bat: dict[str, list[float]] = {}
        for rec in runner.records():
            c[f"mode {rec.mode}"] += 1
            if rec.battery < 0.01:
                c["flat"] += 1
                c[f"flat in {rec.mode}"] += 1
            if rec.mode != "charging":
                continue
            c["charging"] += 1
            bat.setdefault("all", []).append(rec.battery)
            if rec.battery >= self.resume:
                c["full"] += 1
            if rec.leaf.startswith("GrantToCharger") or rec.leaf.startswith("GoToCharger"):
                purpose = policy.purpose(rec.robot) if policy is not None else None
                if purpose is not Purpose.CHARGE:
                    cls = "queued"
                    c[f"queued as {purpose}"] += 1
                elif policy is not None and rec.robot in policy.manager.waiting():
                    cls = "to-ch held"
                else:
                    cls = "to-ch drive"
            elif rec.charging:
                cls = "on-ch"
            else:
                cls = "chg-leaf off"
                c[f"leaf {rec.leaf}"] += 1
            c[cls] += 1
            bat.setdefault(cls, []).append(rec.battery)
        self._named(runner, c)
        if policy is not None:
            m = policy.manager
            c["free chargers"] = sum(1 for ch in policy.chargers if m.holder(ch) is None)
        self.rows.append((now, c))
        bq = " ".join(f"{k}:{_q(v)}" for k, v in sorted(bat.items()))
        extra = " ".join(
            f"{k}={v}"
            for k, v in sorted(c.items())
            if k.startswith(("queued as", "leaf ", "flat in", "mode "))
        )
        print(
            f"t={now:6.0f} charging={c['charging']:4d} "
            + " ".join(f"{k}={c[k]}" for k in COLS)
            + f" free-ch={c['free chargers']} | {extra} | charging battery p10/50/90 {bq}"
            + f" | named charger d>=75m (trigger at resume): {c['far named']}, patrol robots d p50/p90/max "
            + f"{c['d50']}/{c['d90']}/{c['dmax']} m; of the charging: {c['charging, far named']} far named, "
            + f"{c['charging, standing off a charger']} standing off a charger; charges per robot p90/max "
            + f"{c['charges p90']}/{c['charges max']}",
            flush=True,
        )


def _q(v: list[float]) -> str:
    v = sorted(v)
    return "/".join(f"{v[min(len(v) - 1, int(q * len(v)))]:.2f}" for q in (0.1, 0.5, 0.9))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=300)
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--every", type=float, default=30.0, help="simulated s between lines")
    ap.add_argument("--no-traffic", action="store_true")
    ap.add_argument("--traffic", action="append", default=[], help="NAME=VALUE: a traffic config field")
    ap.add_argument("--out", default="out/charging-wave")
    a = ap.parse_args(argv)
    over: dict[str, Any] = {}
    for item in a.traffic:
        k, v = item.split("=", 1)
        over[k] = {"true": True, "false": False, "none": None}.get(v.lower(), v)
        if isinstance(over[k], str):
            over[k] = float(v)
    resume = [0.95]

    def on_config(cfg: Any) -> None:
        cfg.traffic = dataclasses.replace(cfg.traffic, **over)
        resume[0] = cfg.sim.battery.resume

    wave = Wave(a.every, 0.95)
    run = FleetRunner.run

    def run_watched(self: FleetRunner) -> Any:
        wave.resume = resume[0]
        self.observers.append(wave)
        return run(self)

    FleetRunner.run = run_watched  # type: ignore[method-assign]
    t0 = time.monotonic()
    res = run_loadtest(a.robots, a.duration, out_dir=a.out, traffic=not a.no_traffic, on_config=on_config)
    d = res.data
    print(
        f"\n{a.robots} robots, {a.duration:g} s: {d['laps_completed']} laps, {d['deadlocks']} deadlocks, "
        f"{d['collisions']} collisions, {sum(r['battery_min'] < 0.05 for r in d['per_robot'])} below 5 %, "
        f"{time.monotonic() - t0:.0f} s wall"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
