"""The task service's figures (docs/performance.md, "Task service"): all through the real HTTP
API of a real ``fleet run`` (in-process runner or a subprocess), on the kinematic simulator.

* ``latency``: command-to-motion at ``--speed 1``: ``POST /api/tasks`` (a ``go_to`` for an
  idle robot) -> the first simulator step in which that robot moves or turns (then the task
  is canceled); p50/p99 over
  ``--samples`` commands (wall ms).
* ``estop``: ``POST /api/fleet/estop`` -> the end of the first step after which every robot
  has zero speed, at ``--robots`` robots (a generated warehouse; ``--speed 0``, robots
  driving); wall ms, over ``--samples`` e-stops (released and resumed between them).
* ``burst``: ``--tasks`` go_to tasks submitted at once from ``--threads`` HTTP clients:
  submissions per second, p50/p99 submit latency, all persisted (rows in the store), and the
  wall time until every one was assigned.
* ``recovery``: a ``fleet run`` subprocess with ``--robots`` robots and ``--state``, tasks
  submitted, ``kill -9`` mid-run, restart with the same ``--state``: wall time from restart to
  the API answering and to the first new assignment, tasks lost and tasks done twice.

    python bench/bench_service.py latency --samples 30
    python bench/bench_service.py estop --robots 6 100 1000
    python bench/bench_service.py burst --tasks 1000 --robots 100
    python bench/bench_service.py recovery --robots 100
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fleet.config.loader import load_config  # noqa: E402
from fleet.runtime.runner import FleetRunner  # noqa: E402
from fleet.viz.display import NullDisplay  # noqa: E402
from fleet.warehouse import generate_warehouse  # noqa: E402

PATROL = REPO / "configs" / "warehouse_patrol.yaml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(q / 100 * (len(s) - 1))))]


def wait_for(cond: Callable[[], Any], timeout: float, what: str) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.005)
    raise TimeoutError(what)


def config_for(robots: int, tmp: Path) -> Path:
    if robots <= 6:
        return PATROL
    return generate_warehouse(tmp, f"bench{robots}", robots)


class Live:
    """An in-process ``fleet run`` with its API, and a per-step hook on the world."""

    def __init__(
        self, cfg: Path, robots: int, speed: float, tmp: Path, traffic: bool = True, tree: str = "picking"
    ) -> None:
        config = load_config(cfg, robots=robots if cfg == PATROL else None)
        self.runner = FleetRunner(
            config, duration=None, speed=speed, endpoint=f"tcp/127.0.0.1:{free_port()}",
            display=NullDisplay(), traffic=traffic, state_dir=tmp / "state", api="127.0.0.1:0",
            tree_kind=tree,
        )  # fmt: skip
        self.thread = threading.Thread(target=self.runner.run, daemon=True)
        self.thread.start()
        wait_for(lambda: self.runner.host is not None and self.runner.host.api is not None, 300, "API")
        assert self.runner.host is not None and self.runner.host.api is not None
        self.http = httpx.Client(base_url=self.runner.host.api.url, timeout=60)
        self.hooks: list[Callable[[], None]] = []
        world = self.runner.world
        assert world is not None
        self.sim = world.sim  # type: ignore[attr-defined]
        inner = world.advance

        def advance() -> None:
            inner()
            for h in list(self.hooks):
                h()

        world.advance = advance  # type: ignore[method-assign]

    def speeds(self) -> list[float]:
        s = self.sim.state
        return [abs(float(v)) for v in s.v[: len(self.sim.namespaces)]]

    def close(self) -> None:
        self.runner.stop()
        self.thread.join(120)
        self.http.close()


class Watch:
    """A step hook: the wall time of the first step after which ``cond()`` holds."""

    def __init__(self, cond: Callable[[], bool]) -> None:
        self.cond = cond
        self.at: float | None = None
        self.steps = 0
        self.done = threading.Event()

    def __call__(self) -> None:
        self.steps += 1
        if not self.done.is_set() and self.cond():
            self.at = time.perf_counter()
            self.done.set()


def _moving(live: Live, i: int) -> Callable[[], bool]:
    st = live.sim.state
    return lambda: abs(float(st.v[i])) > 1e-6 or abs(float(st.w[i])) > 1e-6


def _stopped(live: Live) -> Callable[[], bool]:
    return lambda: live.runner.latch.engaged and max(live.speeds()) == 0.0


def _driving(live: Live, n: int) -> Callable[[], bool]:
    return lambda: sum(s > 1e-3 for s in live.speeds()) >= max(1, min(10, n // 10))


def _idle_robot(live: Live) -> tuple[str, int] | None:
    names = list(live.sim.namespaces)
    for r in live.http.get("/api/robots").json():
        i = names.index(f"/{r['name']}")
        if r["state"] == "idle" and r["battery"] > 0.5 and abs(float(live.sim.state.v[i])) < 1e-6:
            return r["name"], i
    return None


def _ended(live: Live, tid: str) -> Callable[[], bool]:
    return lambda: live.http.get(f"/api/tasks/{tid}").json()["state"] in ("completed", "failed", "canceled")


def bench_latency(args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    live = Live(PATROL, 6, 1.0, tmp)
    try:
        targets = ["a1_n", "a3_n", "a5_n", "a7_n", "a2_s", "a4_s", "a6_s", "a1_s"]
        lat: list[float] = []
        for k in range(args.samples):
            robot, i = wait_for(lambda: _idle_robot(live), 600, "an idle robot at rest")
            watch = Watch(_moving(live, i))
            live.hooks.append(watch)
            t0 = time.perf_counter()
            spec = {"kind": "go_to", "target": targets[k % len(targets)], "robot": robot, "priority": 100}
            tid = live.http.post("/api/tasks", json=spec).json()["id"]
            if watch.done.wait(60) and watch.at is not None:
                lat.append((watch.at - t0) * 1000)
            live.hooks.remove(watch)
            live.http.post(f"/api/tasks/{tid}/cancel")  # moving is what is measured
            wait_for(_ended(live, tid), 600, tid)
        return {
            "samples": len(lat),
            "p50_ms": round(pct(lat, 50), 1),
            "p99_ms": round(pct(lat, 99), 1),
            "max_ms": round(max(lat), 1),
        }
    finally:
        live.close()


def bench_estop(args: argparse.Namespace, tmp: Path) -> list[dict[str, Any]]:
    out = []
    for n in args.robots:
        cfg = config_for(n, tmp / f"w{n}")
        live = Live(cfg, n, 0.0, tmp / f"e{n}", traffic=not args.no_traffic, tree="patrol")
        try:
            lat, steps = [], []
            for _ in range(args.samples):
                wait_for(_driving(live, n), 900, "robots driving")
                watch = Watch(_stopped(live))
                live.hooks.append(watch)
                t0 = time.perf_counter()
                live.http.post("/api/fleet/estop", json={"by": "bench"})
                watch.done.wait(120)
                live.hooks.remove(watch)
                assert watch.at is not None
                lat.append((watch.at - t0) * 1000)
                steps.append(watch.steps)
                live.http.post("/api/fleet/release", json={"by": "bench"})
                live.http.post("/api/fleet/resume", json={"by": "bench"})
            out.append(
                {
                    "robots": n,
                    "samples": len(lat),
                    "p50_ms": round(pct(lat, 50), 1),
                    "max_ms": round(max(lat), 1),
                    "steps_to_stop_max": max(steps),
                }
            )
            print(json.dumps(out[-1]), flush=True)
        finally:
            live.close()
    return out


def bench_burst(args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    cfg = config_for(args.robots, tmp / "w")
    live = Live(cfg, args.robots, 0.0, tmp / "b", traffic=not args.no_traffic)
    try:
        nodes = [n["name"] for n in live.http.get("/api/roadmap").json()["nodes"]]
        before = len(live.http.get("/api/tasks").json())
        url = live.http.base_url

        def one(k: int) -> tuple[float, str]:
            with httpx.Client(base_url=url, timeout=120) as c:
                t0 = time.perf_counter()
                r = c.post("/api/tasks", json={"kind": "go_to", "target": nodes[(k * 7) % len(nodes)]})
                return (time.perf_counter() - t0) * 1000, r.json()["id"]

        t0 = time.perf_counter()
        with ThreadPoolExecutor(args.threads) as ex:
            res = list(ex.map(one, range(args.tasks)))
        wall = time.perf_counter() - t0
        ids = {tid for _, tid in res}
        db = sqlite3.connect(tmp / "b" / "state" / "tasks.sqlite3")
        stored = db.execute("SELECT COUNT(*) FROM tasks").fetchone()[0] - before
        db.close()
        t1 = time.perf_counter()

        def all_assigned() -> bool:
            ts = live.http.get("/api/tasks").json()
            return all(t["assigned_at"] is not None for t in ts if t["id"] in ids)

        try:
            wait_for(all_assigned, args.assign_timeout, "all assigned")
            assigned_s: float | None = round(time.perf_counter() - t1, 1)
        except TimeoutError:
            assigned_s = None
        ts = live.http.get("/api/tasks").json()
        n_assigned = sum(1 for t in ts if t["id"] in ids and t["assigned_at"] is not None)
        lat = [ms for ms, _ in res]
        return {"robots": args.robots, "tasks": args.tasks, "unique_ids": len(ids), "persisted": stored,
                "submissions_per_s": round(args.tasks / wall, 1), "p50_submit_ms": round(pct(lat, 50), 1),
                "p99_submit_ms": round(pct(lat, 99), 1), "assigned": n_assigned,
                "all_assigned_after_s": assigned_s}  # fmt: skip
    finally:
        live.close()


def bench_recovery(args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    cfg = config_for(args.robots, tmp / "w")
    state, log = tmp / "state", tmp / "run.log"
    env = dict(os.environ, PYTHONPATH=str(REPO))

    def start() -> tuple[subprocess.Popen[bytes], httpx.Client, float]:
        port = free_port()
        t0 = time.perf_counter()
        p = subprocess.Popen(
            [sys.executable, "-m", "fleet.cli", "run", str(cfg), "--speed", str(args.speed), "--no-live", "--tree", "picking",
             "--state", str(state), "--api", f"127.0.0.1:{port}", "--endpoint", f"tcp/127.0.0.1:{free_port()}"],
            cwd=REPO, env=env, stdout=log.open("ab"), stderr=subprocess.STDOUT,
        )  # fmt: skip
        c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)

        def up() -> bool:
            try:
                return c.get("/api/fleet").status_code == 200
            except httpx.HTTPError:
                return False

        wait_for(up, 600, "API")
        return p, c, time.perf_counter() - t0

    p, c, _ = start()
    nodes = [n["name"] for n in c.get("/api/roadmap").json()["nodes"]]
    ids = [c.post("/api/tasks", json={"kind": "go_to", "target": nodes[(k * 11) % len(nodes)]}).json()["id"]
           for k in range(args.tasks)]  # fmt: skip
    wait_for(
        lambda: sum(t["state"] == "completed" for t in c.get("/api/tasks").json()) >= args.tasks // 10,
        900,
        "progress",
    )
    before = {t["id"]: t["state"] for t in c.get("/api/tasks").json()}
    p.send_signal(signal.SIGKILL)
    p.wait()
    c.close()
    db = sqlite3.connect(state / "tasks.sqlite3")
    stored = dict(db.execute("SELECT id, state FROM tasks").fetchall())
    last_seq = db.execute("SELECT MAX(seq) FROM events").fetchone()[0]
    db.close()
    p2, c2, up_s = start()
    t0 = time.perf_counter()
    wait_for(
        lambda: any(
            t["assigned_at"] and t["state"] in ("assigned", "active") for t in c2.get("/api/tasks").json()
        ),
        600,
        "first assignment",
    )
    resume_s = time.perf_counter() - t0 + up_s
    after = {t["id"]: t for t in c2.get("/api/tasks").json()}
    lost = [i for i in ids if i not in after]

    def ended() -> int:
        ts = {t["id"]: t["state"] for t in c2.get("/api/tasks").json()}
        return sum(ts.get(i) in ("completed", "failed") for i in ids)

    try:
        wait_for(lambda: ended() == len(ids), args.done_timeout, "all done")
    except TimeoutError:
        pass
    n_ended = ended()
    db = sqlite3.connect(state / "tasks.sqlite3")
    completions = [r[0] for r in db.execute("SELECT task_id FROM events WHERE event='completed'")]
    done_before = {i for i, s in stored.items() if s == "completed"}
    later = db.execute(
        "SELECT task_id FROM events WHERE seq > ? AND event IN ('assigned', 'completed')", (last_seq,)
    )
    again = sum(1 for (tid,) in later if tid in done_before)
    db.close()
    p2.send_signal(signal.SIGINT)
    p2.wait(120)
    c2.close()
    return {"robots": args.robots, "tasks": len(ids), "completed_before_kill": sum(s == "completed" for s in stored.values()),
            "seen_before_kill": len(before), "restart_to_api_s": round(up_s, 1), "restart_to_first_assignment_s": round(resume_s, 1),
            "lost": len(lost), "duplicated": len(completions) - len(set(completions)) + again,
            "ended_after_restart": n_ended}  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    a = sub.add_parser("latency")
    a.add_argument("--samples", type=int, default=30)
    e = sub.add_parser("estop")
    e.add_argument("--robots", type=int, nargs="+", default=[6, 100, 1000])
    e.add_argument("--samples", type=int, default=5)
    e.add_argument("--no-traffic", action="store_true")
    b = sub.add_parser("burst")
    b.add_argument("--tasks", type=int, default=1000)
    b.add_argument("--robots", type=int, default=100)
    b.add_argument("--threads", type=int, default=8)
    b.add_argument("--assign-timeout", type=float, default=600)
    b.add_argument("--no-traffic", action="store_true")
    r = sub.add_parser("recovery")
    r.add_argument("--robots", type=int, default=100)
    r.add_argument("--tasks", type=int, default=200)
    r.add_argument("--speed", type=float, default=0.0)
    r.add_argument("--done-timeout", type=float, default=600)
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-service-") as d:
        fn = {
            "latency": bench_latency,
            "estop": bench_estop,
            "burst": bench_burst,
            "recovery": bench_recovery,
        }
        out = fn[args.what](args, Path(d))
    print(json.dumps({args.what: out}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
