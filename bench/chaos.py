"""Chaos run: a split fleet on loopback whose processes are killed at random and restarted.

Starts ``fleet sim --state`` (the router and the simulator), ``fleet coordinator --state``
and one ``fleet agent`` per robot on a free 127.0.0.1 port, then every ``--every`` wall
seconds kills one of them (chosen with ``--seed``) with ``kill -9`` and starts it again with
the same arguments, until the simulator's clock reaches ``--duration`` simulated seconds.
It watches the robots' statuses and the coordinator's control state on the bus and reads the
coordinator's durable task book (``tasks.sqlite3``) at the end, and reports:

* **lost** tasks, at the end (after up to ``--settle`` wall s for the last restart to
  settle): a config route missing from the book, a task that ended failed/canceled, a task the
  book has on a robot whose status does not carry its assignment, a task queued while a live
  robot stands idle;
* **done twice**: a task driven by two live robots at the same time (two robots' fresh
  statuses carrying assignments of the same task), an assignment id used for two tasks, or a
  task completed twice;
* **collisions**: the simulator's contact counts summed over the robots (across restarts);
* **recovery**: for each kill, wall s until the restarted process is back (an agent: its
  robot's status again; the coordinator: its control state on the bus again; the simulator:
  every robot's status again) and until the fleet makes progress again (a robot on a task
  drives on: its odometer grows).

Prints a table; exits 1 if anything was lost, done twice or collided. Figures: docs/faults.md.

    python bench/chaos.py --robots 6 --duration 1800 --speed 20 --every 20 --seed 1
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fleet.bus.session import open_session  # noqa: E402
from fleet.bus.status_bus import StatusBus  # noqa: E402
from fleet.messages import StatusRecord  # noqa: E402

FLEET = [sys.executable, "-m", "fleet.cli"]
#: A status older than this (wall s) is not "live" for the done-twice check.
FRESH_S = 1.0


def free_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


@dataclass
class Proc:
    """One fleet process: its name (``sim``, ``coordinator``, ``agent:<robot>``) and arguments."""

    name: str
    args: list[str]
    log: Path
    popen: subprocess.Popen[bytes] | None = None
    starts: int = 0

    def start(self) -> None:
        self.starts += 1
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        f: IO[bytes] = open(self.log, "ab")  # noqa: SIM115 - the child holds it
        f.write(f"--- start {self.starts}\n".encode())
        f.flush()
        self.popen = subprocess.Popen(
            [*FLEET, *self.args], stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, env=env
        )
        f.close()

    def kill9(self) -> None:
        assert self.popen is not None
        self.popen.send_signal(signal.SIGKILL)
        self.popen.wait(timeout=30)


@dataclass
class Kill:
    """One kill: what, when (wall, fleet time), and when it was back and the fleet moving."""

    what: str
    wall: float
    t: float
    back_s: float | None = None
    progress_s: float | None = None


@dataclass
class Watch:
    """What the bus shows: every robot's latest status (and when it came), collisions summed
    across simulator restarts, the moments robots drove and the coordinator spoke."""

    latest: dict[str, tuple[float, StatusRecord]] = field(default_factory=dict)
    collisions: dict[str, int] = field(default_factory=dict)
    collisions_seen: dict[str, int] = field(default_factory=dict)
    last_drive: float = 0.0
    last_control: float = 0.0
    #: (robot, assignment) pairs live at the same moment, per sampling (assignment -> robots)
    shared: set[tuple[str, ...]] = field(default_factory=set)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_status(self, rec: StatusRecord) -> None:
        now = time.monotonic()
        with self.lock:
            prev = self.latest.get(rec.robot)
            if prev is not None and rec.task_id and rec.distance_m > prev[1].distance_m + 0.05:
                self.last_drive = now
            seen = self.collisions_seen.get(rec.robot, 0)
            if rec.collisions < seen:  # a restarted simulator counts from 0 again
                seen = 0
            self.collisions[rec.robot] = self.collisions.get(rec.robot, 0) + rec.collisions - seen
            self.collisions_seen[rec.robot] = rec.collisions
            self.latest[rec.robot] = (now, rec)
            live: dict[str, list[str]] = {}
            for name, (w, r) in self.latest.items():
                if now - w <= FRESH_S and r.task_id and r.mode not in ("idle", "charging"):
                    live.setdefault(r.task_id, []).append(name)
            for assignment, robots in live.items():
                if len(robots) > 1:
                    self.shared.add((assignment, *sorted(robots)))

    def on_control(self, _sample: object) -> None:
        with self.lock:
            self.last_control = time.monotonic()

    def forget(self, robot: str) -> None:
        with self.lock:
            self.latest.pop(robot, None)

    def fleet_t(self) -> float:
        with self.lock:
            return max((r.t for _, r in self.latest.values()), default=0.0)

    def status_since(self, robots: list[str], wall: float) -> bool:
        with self.lock:
            return all(r in self.latest and self.latest[r][0] > wall for r in robots)

    def holding(self, wall: float) -> tuple[dict[str, str], set[str]]:
        """Live robots' assignments (robot -> assignment id) and the live robots with none
        that are not charging, at ``wall``."""
        with self.lock:
            live = [(n, r) for n, (w, r) in self.latest.items() if wall - w <= FRESH_S]
        held = {n: r.task_id for n, r in live if r.task_id}
        return held, {n for n, r in live if not r.task_id and r.mode == "idle" and not r.charging}

    def driving(self, wall: float) -> dict[str, str]:
        """Robots with a fresh status on a task at ``wall`` (robot -> assignment)."""
        with self.lock:
            return {
                n: r.task_id
                for n, (w, r) in self.latest.items()
                if wall - w <= FRESH_S and r.task_id and r.mode == "patrol"
            }


def book_checks(
    book: Path, routes: list[str], shared: set[tuple[str, ...]], holding: dict[str, str], idle: set[str]
) -> tuple[list[str], list[str]]:
    """Lost and done-twice tasks, from the task book and what the bus shows: ``holding`` the
    live robots' assignments (robot -> assignment id on its status), ``idle`` the live robots
    with nothing to do, ``shared`` the assignments seen on two live robots at once."""
    db = sqlite3.connect(f"file:{book}?mode=ro", uri=True)
    try:
        tasks = db.execute("SELECT id, name, state, source, robot, assignment FROM tasks").fetchall()
        pairs = db.execute(
            "SELECT DISTINCT assignment, task_id FROM events WHERE assignment IS NOT NULL"
        ).fetchall()
        completed = db.execute(
            "SELECT task_id, COUNT(*) FROM events WHERE event = 'completed' GROUP BY task_id HAVING COUNT(*) > 1"
        ).fetchall()
    finally:
        db.close()
    task_of: dict[str, set[str]] = {}
    for assignment, task_id in pairs:
        task_of.setdefault(assignment, set()).add(task_id)
    twice = [f"assignment {a} used for {sorted(ts)}" for a, ts in task_of.items() if len(ts) > 1]
    twice += [f"{t} completed {n} times" for t, n in completed]
    for a, *robots in shared:
        twice.append(f"{next(iter(task_of.get(a, {a})))} ({a}) driven by {robots} at once")
    names = {name for _, name, _, source, _, _ in tasks if source == "config"}
    lost = [f"route {r} missing from the task book" for r in routes if r not in names]
    for i, name, state, _, robot, assignment in tasks:
        if state in ("failed", "canceled"):
            lost.append(f"{i} ({name}) {state}")
        elif state in ("assigned", "active") and holding.get(robot) != assignment:
            lost.append(f"{i} ({name}) {state} on {robot} ({assignment}), which does not hold it")
        elif state == "queued" and idle:
            lost.append(f"{i} ({name}) queued while {sorted(idle)} stand idle")
    return lost, twice


# long: the run's loop, kills and restarts in one place
def run(a: argparse.Namespace) -> int:
    rng = random.Random(a.seed)
    out = Path(a.out or tempfile.mkdtemp(prefix="chaos-"))
    out.mkdir(parents=True, exist_ok=True)
    ep = free_endpoint()
    cfg = str(a.config)
    robots = [f"robot{i}" for i in range(1, a.robots + 1)]
    traffic = ["--traffic"] if a.traffic else ["--no-traffic"]
    common = [cfg, "--robots", str(a.robots), "--endpoint", ep]
    sim = Proc("sim", ["sim", *common, "--speed", str(a.speed), "--state", str(out / "sim")], out / "sim.log")
    coord = Proc(
        "coordinator",
        ["coordinator", *common, *traffic, "--no-live", "--state", str(out / "book")],
        out / "coordinator.log",
    )
    agents = [
        Proc(f"agent:{r}", ["agent", *common, "--robot", r, *traffic], out / f"agent-{r}.log") for r in robots
    ]
    procs = [sim, coord, *agents]
    watch = Watch()
    kills: list[Kill] = []
    print(f"chaos: {a.robots} robots, {a.duration:.0f} simulated s at speed {a.speed}, a kill every {a.every} wall s, "
          f"seed {a.seed}, endpoint {ep}, logs in {out}", flush=True)  # fmt: skip
    sim.start()
    session = open_session(ep, "client", connect_timeout_s=60.0)
    bus = StatusBus(session)
    bus.subscribe_statuses(watch.on_status)
    control = session.declare_subscriber("fleet/control/state", watch.on_control)
    book = out / "book" / "tasks.sqlite3"
    routes = [str(r["name"]) for r in yaml.safe_load(Path(a.config).read_text()).get("routes", [])]
    try:
        for p in procs[1:]:
            p.start()
        deadline = time.monotonic() + a.settle
        while not watch.status_since(robots, 0.0) or not watch.driving(time.monotonic()):
            if time.monotonic() > deadline:
                raise SystemExit(f"chaos: the fleet did not start within {a.settle} s (logs in {out})")
            time.sleep(0.2)
        next_kill = time.monotonic() + a.every
        pending: Kill | None = None
        pending_proc: Proc | None = None
        last_print = 0.0
        while watch.fleet_t() < a.duration:
            now = time.monotonic()
            if pending is not None and pending_proc is not None:
                _recovered(pending, pending_proc, watch, robots, a.restart_after)
            if now >= next_kill:
                if (
                    pending is None
                    or (pending.back_s is not None and pending.progress_s is not None)
                    or (now - pending.wall > a.settle)
                ):
                    victim = rng.choice(procs)
                    pending = Kill(victim.name, now, watch.fleet_t())
                    pending_proc = victim
                    kills.append(pending)
                    victim.kill9()
                    if victim.name.startswith("agent:"):  # its last status is not a live robot's
                        watch.forget(victim.name.split(":", 1)[1])
                    time.sleep(a.restart_after)
                    victim.start()
                    next_kill = time.monotonic() + a.every
            if now - last_print > 10.0:
                last_print = now
                print(f"  t={watch.fleet_t():7.0f} s sim, {len(kills)} kills, {len(watch.driving(now))} robots on tasks",
                      flush=True)  # fmt: skip
            time.sleep(0.1)
        # settle: nothing lost and the last kill recovered (or the hang guard)
        deadline = time.monotonic() + a.settle
        while True:
            lost, twice = book_checks(book, routes, watch.shared, *watch.holding(time.monotonic()))
            if pending is not None and pending_proc is not None:
                _recovered(pending, pending_proc, watch, robots, a.restart_after)
            settled = pending is None or (pending.back_s is not None and pending.progress_s is not None)
            if (not lost and settled) or time.monotonic() > deadline:
                break
            time.sleep(1.0)
    finally:
        control.undeclare()
        bus.close()
        session.close()
        for group in (procs[1:], [sim]):  # the simulator last: the others follow its clock
            for p in group:
                if p.popen is not None and p.popen.poll() is None:
                    p.popen.send_signal(signal.SIGINT)
            for p in group:
                if p.popen is not None:
                    try:
                        p.popen.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        p.popen.kill()
                        p.popen.wait(timeout=30)
    collisions = sum(watch.collisions.values())
    tracebacks = [p.name for p in procs if "Traceback" in p.log.read_text(errors="replace")]
    print(f"\n{'kill':>4}  {'process':<14} {'fleet t (s)':>11} {'back (wall s)':>13} {'moving (wall s)':>15}")
    for i, k in enumerate(kills, 1):
        back = f"{k.back_s:.1f}" if k.back_s is not None else "-"
        prog = f"{k.progress_s:.1f}" if k.progress_s is not None else "-"
        print(f"{i:>4}  {k.what:<14} {k.t:>11.0f} {back:>13} {prog:>15}")
    backs = sorted(k.back_s for k in kills if k.back_s is not None)
    progs = sorted(k.progress_s for k in kills if k.progress_s is not None)
    for label, xs in (("back", backs), ("moving again", progs)):
        if xs:
            print(
                f"{label}: median {xs[len(xs) // 2]:.1f} s, max {xs[-1]:.1f} s wall ({len(xs)} of {len(kills)} kills)"
            )
    print(f"fleet time {watch.fleet_t():.0f} s, {len(kills)} kills "
          f"({', '.join(f'{n} {sum(k.what.startswith(n) for k in kills)}' for n in ('sim', 'coordinator', 'agent'))})")  # fmt: skip
    print(f"tasks lost: {len(lost)}   tasks done twice: {len(twice)}   collisions: {collisions}   "
          f"tracebacks: {len(tracebacks)}")  # fmt: skip
    for line in [*lost, *twice, *tracebacks]:
        print(f"  {line}")
    return 1 if lost or twice or collisions or tracebacks else 0


def _recovered(k: Kill, p: Proc, watch: Watch, robots: list[str], restart_after: float) -> None:
    now = time.monotonic()
    if k.back_s is None and _back(p, k.wall, watch, robots):
        k.back_s = now - k.wall
    if k.progress_s is None and watch.last_drive > k.wall + restart_after:
        k.progress_s = watch.last_drive - k.wall


def _back(p: Proc, wall: float, watch: Watch, robots: list[str]) -> bool:
    if p.name == "sim":
        return watch.status_since(robots, wall)
    if p.name == "coordinator":
        return watch.last_control > wall
    return watch.status_since([p.name.split(":", 1)[1]], wall)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, default=ROOT / "configs" / "warehouse_patrol.yaml")
    p.add_argument("--robots", type=int, default=6, help="robots, one `fleet agent` each (default 6)")
    p.add_argument("--duration", type=float, default=1800.0, help="simulated seconds (default 1800)")
    p.add_argument("--speed", type=float, default=20.0, help="the simulator's multiple of real time (20)")
    p.add_argument("--every", type=float, default=20.0, help="wall s between kills (20)")
    p.add_argument(
        "--restart-after", type=float, default=0.5, help="wall s between a kill and the restart (0.5)"
    )
    p.add_argument("--seed", type=int, default=1, help="which processes are killed (default 1)")
    p.add_argument(
        "--settle", type=float, default=120.0, help="hang guard for the start and the end (wall s)"
    )
    p.add_argument(
        "--traffic", action=argparse.BooleanOptionalAction, default=True, help="traffic management"
    )
    p.add_argument("--out", type=Path, help="state directories and logs (default: a new temp dir)")
    a = p.parse_args(argv)
    if a.robots < 1 or a.duration <= 0 or a.speed <= 0 or a.every <= 0:
        p.error("--robots, --duration, --speed and --every must be positive")
    return run(a)


if __name__ == "__main__":
    sys.exit(main())
