"""Where a fleet loses time under traffic management: one in-process ``fleet run`` sampled
every simulated second.

Prints, per robot, the seconds spent in each state (patrolling and driving, patrolling and
waiting for right of way, on the way to a charger, charging, idle, ...), the routes' seconds
without a robot, and for the waits: the nodes and edges robots waited at and who waited for
whom. Deterministic (``--speed 0``), so two code versions compare row by row.

    python bench/traffic_time.py configs/warehouse_patrol.yaml --duration 1800
    python bench/traffic_time.py configs/warehouse_patrol.yaml --duration 1800 --no-traffic

``--trips`` also prints every way to a charger the manager plans (``errand_way``): where the
robot stood, its grant's end, the planned way (m, finishing the grant, with the flow), the
shortest way ignoring every other robot, the way turning back at the first granted node at
least ``turn_back_m`` ahead, and what blocked that way (nodes other robots hold, steps other
robots are about to drive the other way), with a count at the end.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(ROOT))  # run from a checkout; PYTHONPATH chooses another

from fleet.bus.session import free_endpoint  # noqa: E402
from fleet.config.loader import load_config  # noqa: E402
from fleet.runtime.runner import FleetRunner  # noqa: E402


def trace_trips(trips: Counter[str]) -> None:
    """Wrap the manager's ``errand_way`` to print each way to a charger (see ``--trips``)."""
    import fleet.traffic.manager as manager_mod
    from fleet.traffic.paths import HeldByOthers, Oncoming

    plan = manager_mod.errand_way

    def traced(st, r, target, baseline=None):  # type: ignore[no-untyped-def]
        if baseline is not None:  # a robot on its errand looking again (contraflow_m)
            way = plan(st, r, target, baseline=baseline)
            if way is not None and target.startswith("dock:charger:"):
                trips["shortened on the way"] += 1
                print(
                    f"  trip t={st.now:7.1f} {r.name} at {r.path[r.cur]} -> {target[13:]}: shortened on the way"
                )
            return way
        if not target.startswith("dock:charger:"):
            return plan(st, r, target)
        roads, path, cur, g = st.roads, r.path, r.cur, r.g
        planned = roads.shortest(path[g], target, frozenset())
        plan_m = r.cum[g] - r.cum[cur] + (roads.cost(planned, flow=False) if planned else float("nan"))
        straight = roads.shortest(path[cur], target, frozenset(), flow=False)
        k = cur + 1
        while k < g and (roads.pos[path[k]][0] - r.x) ** 2 + (roads.pos[path[k]][1] - r.y) ** 2 < (
            st.params.turn_back_m**2
        ):
            k += 1
        j = min(k, g)
        back = roads.shortest(path[j], target, frozenset(), flow=False)
        back_m = r.cum[j] - r.cum[cur] + roads.cost(back, flow=False) if back else float("nan")
        held, onc = HeldByOthers(st, r.name), Oncoming(st, r.name)
        why = []
        if back and any(n in held for n in back):
            why.append("held")
        if back and any(m in onc for m in zip(back, back[1:], strict=False)):
            why.append("oncoming")
        way = plan(st, r, target)
        shorter = back_m < plan_m - 1e-6
        kind = (
            "turned back" if way is not None else ("blocked: " + "+".join(why) if shorter else "not shorter")
        )
        trips[kind] += 1
        print(
            f"  trip t={st.now:7.1f} {r.name} at {path[cur]} grant to {path[g]} -> {target[13:]}: "
            f"planned {plan_m:.1f} m, straight {roads.cost(straight, flow=False) if straight else 0:.1f} m, "
            f"turning back at {path[j]} {back_m:.1f} m: {kind}"
        )
        return way

    manager_mod.errand_way = traced  # type: ignore[assignment]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", nargs="?", default=str(ROOT / "configs" / "warehouse_patrol.yaml"))
    ap.add_argument("--duration", type=float, default=1800.0)
    ap.add_argument("--no-traffic", action="store_true")
    ap.add_argument("--tree", default="patrol", help="patrol, picking or tasks (the config's initial tasks)")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--trips", action="store_true", help="print every way to a charger the manager plans")
    ap.add_argument("--param", action="append", default=[], help="NAME=VALUE: a TrafficParams field (float)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        help="MODULE.NAME=VALUE: a module constant (float), e.g. fleet.traffic.errands.TOP_UP_BELOW=0",
    )
    a = ap.parse_args(argv)
    for item in a.set:
        import importlib

        target, value = item.split("=", 1)
        mod, _, const = target.rpartition(".")
        setattr(importlib.import_module(mod), const, float(value))
    if a.param:
        import fleet.traffic.policy as policy_mod
        from fleet.traffic.params import TrafficParams

        over = {k: float(v) for k, v in (p.split("=", 1) for p in a.param)}

        def params(**kw: float) -> TrafficParams:
            return TrafficParams(**{**kw, **over})  # type: ignore[arg-type]

        policy_mod.TrafficParams = params  # type: ignore[misc,assignment]
    trip_kinds: Counter[str] = Counter()
    if a.trips:
        trace_trips(trip_kinds)
    config = load_config(a.config)
    runner = FleetRunner(
        config,
        duration=a.duration,
        speed=0.0,
        endpoint=free_endpoint(),
        live=False,
        traffic=not a.no_traffic,
        tree_kind=a.tree,
        out=open("/dev/null", "w"),  # noqa: SIM115 - closed with the process
    )
    states: dict[str, Counter[str]] = defaultdict(Counter)
    at: Counter[str] = Counter()
    whom: Counter[tuple[str, str]] = Counter()
    unassigned: Counter[str] = Counter()
    last = [-1.0]
    trip: dict[str, tuple[float, float]] = {}  # robot -> (t, odometer) when it began to charge
    trips: list[tuple[float, float]] = []  # (s, m) from the charge decision to the charger
    prev_mode: dict[str, str] = {}
    prev_purpose: dict[str, str] = {}
    waited: dict[str, bool] = {}
    set_at: dict[str, float] = {}
    split: list[tuple[bool, float, float]] = []  # (queued, m before the charger path, m in all)
    legs: list[tuple[float, float]] = []  # (granted m, whole path m) when a charge path is set

    def observe(now: float, r: FleetRunner) -> None:
        if now - last[0] < 1.0:
            return
        last[0] = now
        tp = r.traffic_policy
        m = tp.manager if tp is not None else None
        assigned = set()
        if r.coordinator is not None:
            for v in r.coordinator.state.robots.values():
                if v.assignment is not None:
                    assigned.add(v.assignment.name)
        for rec in r.records():
            key = rec.mode
            if rec.mode == "charging" and prev_mode.get(rec.robot) != "charging":
                trip[rec.robot] = (now, rec.distance_m)
            if rec.charging and rec.robot in trip:
                t0, d0 = trip.pop(rec.robot)
                trips.append((now - t0, rec.distance_m - d0))
                split.append(
                    (waited.pop(rec.robot, False), set_at.pop(rec.robot, d0) - d0, rec.distance_m - d0)
                )
            prev_mode[rec.robot] = rec.mode
            tracked = m._st.robots if m is not None else {}
            tr = tracked.get(rec.robot) or tracked.get(rec.ns)
            pur = str(tp.purpose(rec.robot) or "") if tp is not None else ""
            if tr is not None and pur == "charge" and prev_purpose.get(rec.robot) != "charge":
                legs.append((tr.cum[tr.g] - tr.cum[tr.cur], tr.cum[-1] - tr.cum[tr.cur]))
            if rec.robot in trip:
                if pur == "charge-wait":
                    waited[rec.robot] = True
                if pur == "charge" and rec.robot not in set_at:
                    set_at[rec.robot] = rec.distance_m
            prev_purpose[rec.robot] = pur
            if tr is not None:
                key += ":" + (pur or "-")
                if tr.wait_since is not None:
                    key += "/wait"
                    for b in tr.blockers:
                        whom[(rec.robot, b.lstrip("/"))] += 1
                    for x in tr.blocked_on:
                        at[str(x)] += 1
                elif tr.g > tr.cur:
                    key += "/drive"
                else:
                    key += "/stand"
            states[rec.robot][key] += 1
        if r.coordinator is not None:
            for route in r.config.routes:
                if route.name not in assigned:
                    unassigned[route.name] += 1

    runner.observers.append(observe)
    rep = runner.run()
    print(
        f"{a.config} traffic={'off' if a.no_traffic else 'on'} {a.duration:g} s: laps {rep.laps_completed}, "
        f"collisions {rep.collisions}, deadlocks {rep.deadlocks}, lowest battery {100 * rep.min_battery:.1f} %, "
        f"mean wait {rep.mean_wait_s or 0:.0f} s"
    )
    keys = sorted({k for c in states.values() for k in c})
    print("robot    " + " ".join(f"{k:>14}" for k in keys))
    for name in sorted(states):
        print(f"{name:8} " + " ".join(f"{states[name][k]:>14}" for k in keys))
    print("route seconds without a robot:", dict(unassigned))
    if trips:
        ts, ds = sorted(t for t, _ in trips), sorted(d for _, d in trips)
        print(
            f"charge trips: {len(trips)}, to the charger median {ts[len(ts) // 2]:.0f} s / "
            f"{ds[len(ds) // 2]:.1f} m, mean {sum(ts) / len(ts):.0f} s / {sum(ds) / len(ds):.1f} m, "
            f"max {ts[-1]:.0f} s / {ds[-1]:.1f} m"
        )
    for q in (False, True):
        sel = [(a, b) for w, a, b in split if w is q]
        if sel:
            print(
                f"charge trips {'queued' if q else 'direct'}: {len(sel)}, mean m before the charger "
                f"path {sum(a for a, _ in sel) / len(sel):.1f}, mean m in all {sum(b for _, b in sel) / len(sel):.1f}"
            )
    if legs:
        n = len(legs)
        print(
            f"charge paths: {n}, mean granted ahead {sum(g for g, _ in legs) / n:.1f} m, "
            f"mean whole {sum(w for _, w in legs) / n:.1f} m"
        )
    print("waited at (robot-s, resource):", at.most_common(a.top))
    print("waited for (robot-s, who -> blocker):", whom.most_common(a.top))
    if a.trips:
        print("ways to a charger:", dict(trip_kinds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
