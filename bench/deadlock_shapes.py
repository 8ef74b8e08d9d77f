"""Why a load-test fleet under traffic management jams: every deadlock episode of one
``fleet loadtest`` run, classified, and every robot that fell below 5 % of battery.

For each new deadlock episode (a wait-for cycle older than ``traffic.deadlock_s``, the
report's definition) it prints the time, the cycle's size, each member's purpose (patrol,
charge, charge-wait, park), the kind of roadmap node it stands on (``aisle`` inside an aisle,
``end`` an aisle's end on the north / south corridor, ``side`` the west / east corridor,
``lane`` the parking lanes, ``dock`` a charger / parking spur, ``via`` a spur's junction, ``cell`` a piece of a cut edge) and
the node it waits for. At the end: the episodes counted by shape (sorted purposes and node
kinds), and the flat robots with where and in which mode they fell below 5 %. Every 5 s it
also counts the waiting robots by what holds each back (``why``) and by what the queue it
waits in ends in (``queue heads``): a moving robot, or a wait-for cycle named by its shape
(``cycle 2: end>via via>end``: each member's node kind, ``>`` the kind it asks for, ``^``
when it was sent back the way it came).

Charging: every robot that falls below 5 % is printed with its charging trip so far (one line
per 5 s: battery, phase, node, target charger, nodes left, blockers, and what changed its
path: a deadlock resolution, or the errand code that gave it a new path). At the end, the
charging robot-samples by phase (on a charger, driving, waiting), the free chargers, and the
trips to a charger: seconds from the trigger to the charger, battery used, chargers targeted.
Deterministic (same seed, same run), so two code versions compare episode by episode.

    python bench/deadlock_shapes.py --robots 100 --duration 900
    python bench/deadlock_shapes.py --robots 100 --duration 900 --no-traffic
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
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

LOW = 0.05

#: Recent ``TrafficManager.set_path`` calls: (time, robot, the errand code that made it).
SET_PATHS: list[tuple[float, str, str]] = []


def _trace_set_path() -> None:
    """Record who gives robots new paths (the errand that called ``set_path``)."""
    from fleet.traffic.manager import TrafficManager

    orig = TrafficManager.set_path

    def set_path(self: TrafficManager, robot: str, nodes: Any, now: float, *a: Any, **kw: Any) -> int:
        f = sys._getframe(1)
        names = []
        while f is not None and len(names) < 4:
            names.append(f.f_code.co_name)
            f = f.f_back  # type: ignore[assignment]
        SET_PATHS.append((now, robot, "/".join(names[1:])))
        if len(SET_PATHS) > 4000:
            del SET_PATHS[:2000]
        return orig(self, robot, nodes, now, *a, **kw)

    TrafficManager.set_path = set_path  # type: ignore[method-assign]


def kind(node: str) -> str:
    """The kind of a generated warehouse's roadmap node (see the module docstring)."""
    if node.startswith("dock:"):
        return "dock"
    if node.startswith("via:"):
        return "via"
    if node.startswith("cell:"):
        return "cell"
    col, _, sfx = node.partition("_")
    if sfx.startswith("p"):
        return "lane"
    if col in ("w", "e"):
        return "side"
    return "end" if sfx in ("s", "n") else "aisle"


class Watch:
    """A runner observer: new deadlock episodes and robots going below :data:`LOW`."""

    def __init__(self, out: Any) -> None:
        self.out = out
        self.seen = 0
        self.shapes: Counter[str] = Counter()
        self.low: dict[str, tuple[float, str, str]] = {}
        self.last = -1.0
        self.waits: Counter[str] = Counter()
        self.why: Counter[str] = Counter()
        self.heads: Counter[str] = Counter()
        self.trigger: dict[str, tuple[float, float]] = {}  # robot -> (t, battery) it began to charge
        # robot -> its charging episode so far, one sample every 5 s (bounded: one episode)
        self.trace: dict[str, list[str]] = {}
        self.phases: Counter[str] = Counter()  # charging robot-samples by phase
        self.free_chargers: list[int] = []
        # finished trips to a charger: (seconds from the trigger, battery used, targets tried)
        self.trips: list[tuple[float, float, int]] = []
        self.targets: dict[str, set[str]] = {}

    def __call__(self, now: float, runner: FleetRunner) -> None:
        policy = getattr(runner, "traffic_policy", None)
        if now - self.last >= 5.0:
            self.last = now
            if policy is not None:
                m0 = policy.manager
                self.free_chargers.append(sum(1 for c in policy.chargers if m0.holder(c) is None))
            for rec in runner.records():
                if rec.mode == "charging" and rec.robot not in self.trigger:
                    self.trigger[rec.robot] = (now, rec.battery)
                    self.trace[rec.robot] = []
                elif rec.mode != "charging":
                    self.trigger.pop(rec.robot, None)
                    self.trace.pop(rec.robot, None)
                    self.targets.pop(rec.robot, None)
                if rec.mode == "charging" and policy is not None and policy.manager.knows(rec.robot):
                    r0 = policy.manager._st.robots[rec.robot]  # noqa: SLF001
                    here0 = r0.path[r0.cur] if r0.path else "?"
                    end0 = r0.path[-1] if r0.path else "?"
                    waiting0 = r0.wait_since is not None
                    phase = (
                        "on charger"
                        if here0.startswith("dock:charger")
                        else f"{policy.purpose(rec.robot) or 'none'} {'waiting' if waiting0 else 'moving'}"
                    )
                    self.phases[phase] += 1
                    tried = self.targets.setdefault(rec.robot, set())
                    if phase == "on charger":
                        if rec.robot in self.trigger and "" not in tried:
                            t1, b1 = self.trigger[rec.robot]
                            self.trips.append((now - t1, b1 - rec.battery, len(tried)))
                            tried.clear()
                            tried.add("")  # arrived: counted once
                    elif "" not in tried and end0.startswith("dock:charger"):
                        tried.add(end0)
                    about0 = (
                        [
                            msg
                            for te, msg in policy.manager._st.metrics.events[-200:]  # noqa: SLF001
                            if te > now - 5.0 and rec.robot in msg.split()
                        ]
                        + [who for te, r1, who in SET_PATHS[-400:] if r1 == rec.robot and te > now - 5.0]
                    )
                    self.trace[rec.robot].append(
                        f"{now:6.0f} {rec.battery:4.0%} {phase:18s} at {here0} to {end0} "
                        f"({len(r0.path) - r0.cur} nodes) on {sorted(r0.blockers)} {about0[-3:]}"
                    )
                if rec.battery < LOW and rec.robot not in self.low:
                    where = "?"
                    if policy is not None and policy.manager.knows(rec.robot):
                        where = (
                            policy.manager.path(rec.robot)[:1][0] if policy.manager.path(rec.robot) else "?"
                        )
                    if policy is not None and policy.manager.knows(rec.robot):
                        r = policy.manager._st.robots[rec.robot]  # noqa: SLF001
                        print(
                            f"  {now:7.1f} {rec.robot} below {LOW:.0%}: {policy.purpose(rec.robot)}, "
                            f"waiting {r.wait_since is not None} on {sorted(r.blockers)}, "
                            f"ahead {r.path[r.cur : r.cur + 16]}",
                            file=self.out,
                        )
                    for line in self.trace.get(rec.robot, [])[-40:]:
                        print(f"      {line}", file=self.out)
                    t0, b0 = self.trigger.get(rec.robot, (now, rec.battery))
                    self.low[rec.robot] = (now, f"{rec.mode} since {now - t0:.0f} s, from {b0:.0%}", where)
        if policy is None:
            return
        if now - self.last < 1e-9:
            st0 = policy.manager._st  # noqa: SLF001
            for n in st0.waiting:
                r = st0.robots[n]
                if not r.path or r.wait_since is None:
                    continue
                mine = str(policy.purpose(n) or "none")
                theirs = ",".join(sorted({str(policy.purpose(b) or "none") for b in r.blockers})) or "-"
                self.waits[f"{mine:11s} at {kind(r.path[r.cur]):5s} on {theirs}"] += 1
                self.why[why(st0, r)] += 1
                self.heads[head(st0, r)] += 1
        events = policy.deadlock_events
        if policy.deadlocks <= self.seen:
            return
        new = events[-(policy.deadlocks - self.seen) :]
        self.seen = policy.deadlocks
        st = policy.manager._st  # noqa: SLF001 - a diagnostic reads the manager's state
        for t, members in new:
            parts = []
            for name in members:
                r = st.robots[name]
                here = r.path[r.cur] if r.path else "?"
                want = r.path[r.g + 1] if r.path and r.g + 1 < len(r.path) else "-"
                purpose = str(policy.purpose(name) or "none")
                parts.append((purpose, kind(here), name, here, want, sorted(r.blockers)))
            shape = f"{len(members)}: " + " ".join(sorted(f"{p}@{k}" for p, k, *_ in parts))
            self.shapes[shape] += 1
            print(f"t={t:7.1f} {shape}", file=self.out)
            for p, k, name, here, want, blk in parts:
                print(
                    f"    {name:9s} {p:11s} at {here:22s} ({k:5s}) wants {want:22s} on {blk}", file=self.out
                )
                r = st.robots[name]
                print(
                    f"      path {r.path[max(0, r.cur - 4) : r.cur]} | {r.path[r.cur : r.cur + 6]}",
                    file=self.out,
                )
            about = [
                (te, msg)
                for te, msg in st.metrics.events[-400:]
                if te > t - 60 and any(m in msg for m in members)
            ]
            for te, msg in about[-8:]:
                print(f"      {te:7.1f} {msg}", file=self.out)
            self.out.flush()


def why(st: Any, r: Any) -> str:
    """Which rule holds the waiting robot ``r`` back: the block it asks for (``corridor``: a
    whole corridor, following refused; ``node``: one node) and how each blocker stands to it
    (``lead``: drives ``r``'s way ahead of it, with the gap in m; ``cross``: another way;
    ``claim``: only claims it), the closest blocker deciding."""
    from fleet.traffic.grants import block

    idx = block(st, r)
    want = "corridor" if len(idx) > 1 else "node"
    ahead = r.path[r.cur + 1 : r.cur + 12]
    best = "none"
    bestd = 1e9
    for b in sorted(r.blockers):
        o = st.robots.get(b)
        if o is None or not o.path:
            continue
        d = ((o.x - r.x) ** 2 + (o.y - r.y) ** 2) ** 0.5
        held = st.table.holder(r.path[idx[0]]) == b or any(st.table.holder(r.path[j]) == b for j in idx)
        if not held:
            rel = "claim"
        else:
            onext = o.path[o.cur + 1 : o.cur + 3]
            here = o.path[o.cur]
            same = (
                here in ahead
                and all(n in ahead for n in onext[:1])
                and (not onext or ahead.index(onext[0]) > ahead.index(here))
            )
            rel = "lead" if same else "cross"
        if d < bestd:
            bestd = d
            best = rel if rel != "lead" else f"lead {min(int(d // 2) * 2, 12):2d}m+"
    return f"{want:8s} {kind(r.path[r.cur]):5s} {best}"


def head(st: Any, r: Any) -> str:
    """What the queue ``r`` waits in waits for: follow each waiting robot's nearest blocker
    to the first one that is not waiting (``moving``: the queue drains) or round a cycle;
    that robot's :func:`why` (or ``moving``), with ``purpose`` of the head."""
    seen = {r.name}
    chain = [r.name]
    cur = r
    for _ in range(50):
        if not cur.blockers:
            break
        nxt = min(
            (st.robots[b] for b in cur.blockers if b in st.robots),
            key=lambda o: (o.x - cur.x) ** 2 + (o.y - cur.y) ** 2,
            default=None,
        )
        if nxt is None:
            break
        if nxt.name in seen:
            return f"cycle {cycle_shape(st, chain[chain.index(nxt.name) :])}"
        seen.add(nxt.name)
        chain.append(nxt.name)
        if nxt.wait_since is None:
            return f"moving head: {why(st, cur)}"
        cur = nxt
    return f"waiting head: {why(st, cur)}"


def cycle_shape(st: Any, names: list[str]) -> str:
    """The shape of a wait-for cycle of nearest blockers: its size and, for each member in
    order, the kind of node it stands on and of the node it asks for, and whether it was
    sent back the way it came (``^``: its next node is the node it came from)."""
    parts = []
    for n in names:
        o = st.robots[n]
        if not o.path:
            parts.append("?")
            continue
        want = o.path[o.g + 1] if o.g + 1 < len(o.path) else "-"
        back = "^" if o.cur > 0 and o.cur + 1 < len(o.path) and o.path[o.cur + 1] == o.path[o.cur - 1] else ""
        parts.append(f"{kind(o.path[o.cur])}>{kind(want) if want != '-' else '-'}{back}")
    k = min(range(len(parts)), key=lambda i: parts[i:] + parts[:i])
    return f"{len(names)}: " + " ".join(parts[k:] + parts[:k])


def _num(v: str) -> float | None:
    """A float, or ``None`` for ``none`` (e.g. ``--traffic cell_m=none``: edges not cut)."""
    return None if v.lower() == "none" else float(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--start-offset",
        type=int,
        default=0,
        help="robot i starts with the battery of robot i+K of the generated fleet (another run: "
        "the seed only draws task shelves, so it does not change a patrol load test)",
    )
    ap.add_argument("--no-traffic", action="store_true")
    ap.add_argument("--out", default="out/deadlock-shapes")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        help="MODULE.NAME=VALUE: a module constant (int if all digits, else float), e.g. fleet.traffic.errands.CHARGE_REACH_M=60",
    )
    ap.add_argument(
        "--traffic",
        action="append",
        default=[],
        help="NAME=VALUE: a field of the config's traffic section (none: None)",
    )
    ap.add_argument(
        "--battery", action="append", default=[], help="NAME=VALUE: a field of the config's battery model"
    )
    ap.add_argument(
        "--param", action="append", default=[], help="NAME=VALUE: a TrafficParams default (float)"
    )
    a = ap.parse_args(argv)
    if a.param:
        import fleet.traffic.policy as policy_mod
        from fleet.traffic.params import TrafficParams

        pover = {k: _num(v) for k, v in (p.split("=", 1) for p in a.param)}

        def params(**kw: Any) -> TrafficParams:
            return TrafficParams(**{**kw, **pover})

        policy_mod.TrafficParams = params  # type: ignore[misc,assignment]
    for item in a.set:
        target, value = item.split("=", 1)
        mod, _, const = target.rpartition(".")
        setattr(importlib.import_module(mod), const, int(value) if value.isdigit() else float(value))
    watch = Watch(sys.stdout)
    _trace_set_path()
    run = FleetRunner.run

    def run_watched(self: FleetRunner) -> Any:
        self.observers.append(watch)
        return run(self)

    FleetRunner.run = run_watched  # type: ignore[method-assign]
    t0 = time.monotonic()
    over = {k: _num(v) for k, v in (t.split("=", 1) for t in a.traffic)}

    bover = {k: float(v) for k, v in (t.split("=", 1) for t in a.battery)}

    def on_config(cfg: Any) -> None:
        cfg.traffic = dataclasses.replace(cfg.traffic, **over)
        cfg.sim = dataclasses.replace(cfg.sim, battery=dataclasses.replace(cfg.sim.battery, **bover))
        if a.start_offset:
            from fleet.warehouse import start_battery

            cfg.robots = [
                dataclasses.replace(r, battery=start_battery(i + a.start_offset))
                for i, r in enumerate(cfg.robots)
            ]

    res = run_loadtest(
        a.robots, a.duration, out_dir=a.out, seed=a.seed, traffic=not a.no_traffic, on_config=on_config
    )
    d = res.data
    lowest = min(r["battery_min"] for r in d["per_robot"])
    print(
        f"\n{a.robots} robots, {a.duration:g} s: {d['laps_completed']} laps, {d['deadlocks']} deadlocks, "
        f"{d['collisions']} collisions, lowest battery {lowest:.1%}, "
        f"{sum(r['battery_min'] < LOW for r in d['per_robot'])} below {LOW:.0%}, mean/p95 wait "
        f"{d.get('mean_wait_s')}/{d.get('p95_wait_s')} s, {time.monotonic() - t0:.0f} s wall"
    )
    print("deadlock shapes:")
    for shape, n in watch.shapes.most_common():
        print(f"  {n:4d}  {shape}")
    print("waiting robot-samples (every 5 s): purpose at node kind on the blockers' purposes")
    for what, n in watch.waits.most_common(15):
        print(f"  {n:6d}  {what}")
    print("why (every 5 s): block asked, node kind, the nearest blocker's relation (lead: same way, gap)")
    for what, n in watch.why.most_common(25):
        print(f"  {n:6d}  {what}")
    print(
        "queue heads (every 5 s): what the robot a waiting robot's queue starts at waits for "
        "(cycle: its size, each member's node kind > the kind it asks for, ^ sent back)"
    )
    for what, n in watch.heads.most_common(30):
        print(f"  {n:6d}  {what}")
    print("charging robot-samples (every 5 s) by phase")
    for what, n in watch.phases.most_common():
        print(f"  {n:6d}  {what}")
    fc = watch.free_chargers
    if fc:
        print(f"free chargers (not held): mean {sum(fc) / len(fc):.1f}, min {min(fc)}, samples {len(fc)}")
    if watch.trips:

        def pct(xs: list[float], q: float) -> float:
            xs = sorted(xs)
            return xs[min(len(xs) - 1, int(q * len(xs)))]

        dur = [t for t, _, _ in watch.trips]
        used = [u for _, u, _ in watch.trips]
        tried_n = [k for _, _, k in watch.trips]
        print(
            f"trips to a charger: {len(dur)}, s from trigger p50/p90/max {pct(dur, 0.5):.0f}/{pct(dur, 0.9):.0f}/"
            f"{max(dur):.0f}, battery used p50/p90/max {pct(used, 0.5):.0%}/{pct(used, 0.9):.0%}/{max(used):.0%}, "
            f"chargers targeted mean {sum(tried_n) / len(tried_n):.1f} max {max(tried_n)}"
        )
    print(f"below {LOW:.0%}:")
    for name, (t, mode, where) in sorted(watch.low.items(), key=lambda kv: kv[1][0]):
        print(f"  t={t:7.1f} {name:9s} {mode:9s} at {where} ({kind(where)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
