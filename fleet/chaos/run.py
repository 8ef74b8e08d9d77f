"""A chaos run: a fleet on a free 127.0.0.1 port whose processes are killed with ``kill -9`` at
random and started again, until the fleet has run a given simulated time.

Two deployments (``mode``):

* ``split``: ``fleet sim --state`` (the router and the simulator), ``fleet coordinator
  --state`` (its durable task book) and one ``fleet agent`` per robot; every ``every`` wall
  seconds one of them, chosen by the seeded generator, is killed and started again with the
  same arguments ``restart_after`` wall seconds later;
* ``run``: one ``fleet run --state`` process (router, simulator, agents and coordinator in
  one), killed and started again the same way. It resumes its tasks from its durable task book
  and its robots from its simulator's snapshot in the same directory (poses, batteries,
  docking states, the clock; :mod:`fleet.runtime.snapshot`); the fleet time of the run is
  summed over the restarts (a clock that went back is caught up with, not counted twice).

The next kill waits until the last one has recovered (or ``settle`` wall seconds passed), so
one process is down at a time. The run watches the robots' statuses and the coordinator's
control state on the bus (as the ``observer`` identity on a secured bus) and reads the task
book at the end: tasks lost, tasks done twice (:func:`fleet.chaos.watch.book_checks`),
collisions (the simulator's counts summed across restarts), tracebacks in any process's log,
and per kill how long until the process was back and the fleet moving again.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Literal

from fleet.bus.session import Secure, open_session, undeclare_all
from fleet.bus.status_bus import StatusBus
from fleet.chaos.watch import MIN_BATTERY, Sample, Watch, book_checks, crossing_lines
from fleet.errors import BusError

#: The ``fleet`` command line of the processes (this interpreter, this source tree).
FLEET = [sys.executable, "-m", "fleet.cli"]
ROOT = Path(__file__).resolve().parents[2]
#: Wall seconds between two progress lines.
PROGRESS_S = 10.0

Mode = Literal["split", "run"]


@dataclass(frozen=True)
class ChaosSpec:
    """What to run: ``config`` with ``robots`` robots for ``duration`` simulated seconds at
    ``speed`` x real time, a kill every ``every`` wall s (seeded by ``seed``), the restart
    ``restart_after`` wall s after the kill, ``settle`` the hang guard (wall s) of the start,
    of a recovery and of the end; ``out`` the state directories and logs; ``secure`` a key
    directory (every process then runs on the secured bus); ``mode`` the deployment."""

    config: Path
    robots: int
    duration: float
    endpoint: str
    out: Path
    speed: float = 10.0
    every: float = 8.0
    seed: int = 1
    restart_after: float = 0.5
    settle: float = 120.0
    traffic: bool = True
    secure: Path | None = None
    mode: Mode = "split"
    routes: tuple[str, ...] = ()
    #: Which kinds of process may be killed (``sim``, ``coordinator``, ``agent``, ``run``);
    #: empty: every kind.
    kinds: tuple[str, ...] = ()


@dataclass
class Proc:
    """One fleet process: its name (``sim``, ``coordinator``, ``agent:<robot>``, ``run``), its
    ``fleet`` arguments and its log (each start appends to it)."""

    name: str
    args: list[str]
    log: Path
    popen: subprocess.Popen[bytes] | None = None
    starts: int = 0

    def start(self) -> None:
        self.starts += 1
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
        f: IO[bytes] = open(self.log, "ab")  # noqa: SIM115 - the child holds it
        f.write(f"--- start {self.starts}\n".encode())
        f.flush()
        self.popen = subprocess.Popen([*FLEET, *self.args], stdout=f, stderr=subprocess.STDOUT, env=env)
        f.close()

    def kill9(self) -> None:
        assert self.popen is not None
        self.popen.send_signal(signal.SIGKILL)
        self.popen.wait(timeout=30)

    def stop(self) -> None:
        """Ctrl-C, then ``kill -9`` after 30 wall s."""
        if self.popen is None or self.popen.poll() is not None:
            return
        self.popen.send_signal(signal.SIGINT)
        try:
            self.popen.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            self.popen.wait(timeout=30)


@dataclass
class Kill:
    """One kill: of what, when (wall, fleet time elapsed), and after how many wall seconds
    the process was back and the fleet moving again (``None``: not seen)."""

    what: str
    wall: float
    t: float
    back_s: float | None = None
    moving_s: float | None = None

    @property
    def settled(self) -> bool:
        return self.back_s is not None and self.moving_s is not None


@dataclass
class ChaosResult:
    """What a chaos run found (see the module docstring); ``ok`` when nothing was lost, done
    twice, collided or printed a traceback."""

    spec: ChaosSpec
    elapsed: float = 0.0
    kills: list[Kill] = field(default_factory=list)
    lost: list[str] = field(default_factory=list)
    twice: list[str] = field(default_factory=list)
    collisions: int = 0
    tracebacks: list[str] = field(default_factory=list)
    #: The lowest battery fraction a robot reported (not part of the verdict), and which robot.
    min_battery: tuple[float, str] = (1.0, "")
    #: Per robot, (fleet time s, battery, mode) samples (:attr:`Watch.timeline`).
    timeline: dict[str, list[Sample]] = field(default_factory=dict)
    #: Where and doing what each robot went below :data:`MIN_BATTERY` (:attr:`Watch.crossed`).
    crossed: dict[str, tuple[Sample, Sample | None]] = field(default_factory=dict)

    @property
    def flat(self) -> bool:
        """Whether a robot's battery went below :data:`MIN_BATTERY` (the fleet ran flat)."""
        return self.min_battery[0] < MIN_BATTERY

    @property
    def ok(self) -> bool:
        return not (self.lost or self.twice or self.collisions or self.tracebacks or self.flat)


def processes(spec: ChaosSpec) -> list[Proc]:
    """The processes of ``spec``'s deployment; the first one hosts the router."""
    cfg, out = str(spec.config.resolve()), spec.out
    common = [cfg, "--robots", str(spec.robots), "--endpoint", spec.endpoint]
    common += ["--secure", str(spec.secure)] if spec.secure is not None else []
    traffic = ["--traffic"] if spec.traffic else ["--no-traffic"]
    if spec.mode == "run":
        args = [
            "run",
            *common,
            *traffic,
            "--speed",
            str(spec.speed),
            "--no-live",
            "--state",
            str(out / "book"),
        ]
        return [Proc("run", args, out / "run.log")]
    sim = Proc(
        "sim", ["sim", *common, "--speed", str(spec.speed), "--state", str(out / "sim")], out / "sim.log"
    )
    coord = Proc(
        "coordinator",
        ["coordinator", *common, *traffic, "--no-live", "--state", str(out / "book")],
        out / "coordinator.log",
    )
    agents = [
        Proc(f"agent:{r}", ["agent", *common, "--robot", r, *traffic], out / f"agent-{r}.log")
        for r in robot_names(spec.robots)
    ]
    return [sim, coord, *agents]


def robot_names(n: int) -> list[str]:
    return [f"robot{i}" for i in range(1, n + 1)]


def run_chaos(spec: ChaosSpec, say: Callable[[str], None] = print) -> ChaosResult:
    """Run the chaos of ``spec`` (see the module docstring), saying its progress through
    ``say``. Raises :class:`BusError` if the bus cannot be watched or the fleet does not start
    within ``spec.settle`` wall s."""
    spec.out.mkdir(parents=True, exist_ok=True)
    procs = processes(spec)
    robots = robot_names(spec.robots)
    watch = Watch()
    result = ChaosResult(spec)
    procs[0].start()
    try:
        secure = Secure(spec.secure, "observer") if spec.secure is not None else None
        session = open_session(spec.endpoint, "client", connect_timeout_s=60.0, secure=secure)
    except BusError:
        procs[0].stop()
        raise
    bus = StatusBus(session)
    bus.subscribe_statuses(watch.on_status)
    control = session.declare_subscriber("fleet/control/state", watch.on_control)
    try:
        for p in procs[1:]:
            p.start()
        _wait_start(spec, watch, robots)
        pending = _kill_loop(spec, procs, watch, robots, result, say)
        result.elapsed = watch.fleet_elapsed()  # the chaos; the settling after it is not counted
        _settle(spec, watch, robots, result, pending)
    finally:
        undeclare_all([control])
        bus.close()
        session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves Session.close unannotated
        for p in procs[1:]:  # the router's host last: the others follow its clock
            p.stop()
        procs[0].stop()
    result.collisions = sum(watch.collisions.values())
    result.min_battery = watch.min_battery
    with watch.lock:
        result.timeline = {r: list(line) for r, line in watch.timeline.items()}
        result.crossed = dict(watch.crossed)
    write_timeline(spec.out / "battery.csv", result.timeline)
    result.tracebacks = [p.name for p in procs if "Traceback" in p.log.read_text(errors="replace")]
    return result


#: The header of ``battery.csv`` (:func:`write_timeline`).
TIMELINE_HEADER = "robot,t_s,battery,mode,charging,x,y,leaf"


def write_timeline(path: Path, timeline: dict[str, list[Sample]]) -> None:
    """Write the battery samples as CSV (:data:`TIMELINE_HEADER`; t the fleet time, s)."""
    rows = [
        f"{r},{p.t:.1f},{p.battery:.4f},{p.mode},{int(p.charging)},{p.x:.2f},{p.y:.2f},{p.leaf.replace(',', ' ')}"
        for r, line in sorted(timeline.items())
        for p in line
    ]
    path.write_text("\n".join([TIMELINE_HEADER, *rows]) + "\n")


def _wait_start(spec: ChaosSpec, watch: Watch, robots: list[str]) -> None:
    deadline = time.monotonic() + spec.settle
    while not watch.status_since(robots, 0.0) or not watch.driving(time.monotonic()):
        if time.monotonic() > deadline:
            raise BusError(f"chaos: the fleet did not start within {spec.settle:g} s (logs in {spec.out})")
        time.sleep(0.2)


def _kill_loop(
    spec: ChaosSpec,
    procs: list[Proc],
    watch: Watch,
    robots: list[str],
    result: ChaosResult,
    say: Callable[[str], None],
) -> tuple[Kill, Proc] | None:
    """Kill and restart until the fleet ran ``spec.duration``; the last kill and its process."""
    rng = random.Random(spec.seed)
    victims = [p for p in procs if not spec.kinds or p.name.split(":", 1)[0] in spec.kinds]
    next_kill = time.monotonic() + spec.every
    pending: tuple[Kill, Proc] | None = None
    last_say = time.monotonic()
    while watch.fleet_elapsed() < spec.duration:
        now = time.monotonic()
        if pending is not None:
            _recovered(*pending, watch, robots, spec.restart_after)
        if now >= next_kill and (
            pending is None or pending[0].settled or now - pending[0].wall > spec.settle
        ):
            victim = rng.choice(victims)
            kill = Kill(victim.name, now, watch.fleet_elapsed())
            pending = (kill, victim)
            result.kills.append(kill)
            victim.kill9()
            if victim.name.startswith("agent:"):  # its last status is not a live robot's
                watch.forget(victim.name.split(":", 1)[1])
            time.sleep(spec.restart_after)
            victim.start()
            next_kill = time.monotonic() + spec.every
        if now - last_say >= PROGRESS_S:
            last_say = now
            last = result.kills[-1] if result.kills else None
            back = (
                ""
                if last is None
                else f", last {last.what} back {_s(last.back_s)} moving {_s(last.moving_s)}"
            )
            say(
                f"[chaos t={watch.fleet_elapsed():7.0f} s sim] {len(result.kills)} kills, "
                f"{len(watch.driving(now))} robots on tasks{back}"
            )
        time.sleep(0.1)
    return pending


def _settle(
    spec: ChaosSpec, watch: Watch, robots: list[str], result: ChaosResult, pending: tuple[Kill, Proc] | None
) -> None:
    """Wait (up to ``spec.settle`` wall s) until nothing is lost and the last kill recovered;
    then record what is lost and done twice."""
    book = spec.out / "book" / "tasks.sqlite3"
    deadline = time.monotonic() + spec.settle
    while True:
        lost, twice = book_checks(book, list(spec.routes), watch.shared, *watch.holding(time.monotonic()))
        if pending is not None:
            _recovered(*pending, watch, robots, spec.restart_after)
        if (not lost and (pending is None or pending[0].settled)) or time.monotonic() > deadline:
            break
        time.sleep(1.0)
    result.lost, result.twice = lost, twice


def _recovered(k: Kill, p: Proc, watch: Watch, robots: list[str], restart_after: float) -> None:
    now = time.monotonic()
    if k.back_s is None and _back(p, k.wall, watch, robots):
        k.back_s = now - k.wall
    if k.moving_s is None and watch.last_drive > k.wall + restart_after:
        k.moving_s = watch.last_drive - k.wall


def _back(p: Proc, wall: float, watch: Watch, robots: list[str]) -> bool:
    if p.name in ("sim", "run"):
        return watch.status_since(robots, wall)
    if p.name == "coordinator":
        return watch.last_control > wall
    return watch.status_since([p.name.split(":", 1)[1]], wall)


def _s(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f} s"


def report_lines(res: ChaosResult) -> list[str]:
    """The final table: one line per kill, recovery medians and maxima, the verdict."""
    kills = res.kills
    lines = [
        f"{'kill':>4}  {'process':<14} {'fleet t (s)':>11} {'back (wall s)':>13} {'moving (wall s)':>15}"
    ]
    for i, k in enumerate(kills, 1):
        back = f"{k.back_s:.1f}" if k.back_s is not None else "-"
        moving = f"{k.moving_s:.1f}" if k.moving_s is not None else "-"
        lines.append(f"{i:>4}  {k.what:<14} {k.t:>11.0f} {back:>13} {moving:>15}")
    kinds = ("run",) if res.spec.mode == "run" else ("sim", "coordinator", "agent")
    for kind in kinds:
        for label, xs in (
            ("back", sorted(k.back_s for k in kills if k.back_s is not None and k.what.startswith(kind))),
            (
                "moving again",
                sorted(k.moving_s for k in kills if k.moving_s is not None and k.what.startswith(kind)),
            ),
        ):
            if xs:
                lines.append(
                    f"{kind} {label}: median {xs[len(xs) // 2]:.1f} s, max {xs[-1]:.1f} s wall ({len(xs)} kills)"
                )
    counts = ", ".join(f"{n} {sum(k.what.startswith(n) for k in kills)}" for n in kinds)
    lines.append(f"fleet time {res.elapsed:.0f} s, {len(kills)} kills ({counts})")
    low, robot = res.min_battery
    verdict = f"below {MIN_BATTERY:.0%}: ran flat" if res.flat else f"at least {MIN_BATTERY:.0%}"
    lines.append(f"lowest battery seen: {low:.1%}{f' ({robot})' if robot else ''} ({verdict})")
    lines += [f"  {line}" for line in crossing_lines(res.crossed)]
    lines.append(
        f"tasks lost: {len(res.lost)}   tasks done twice: {len(res.twice)}   collisions: {res.collisions}   "
        f"tracebacks: {len(res.tracebacks)}   flat batteries: {int(res.flat)}"
    )
    lines += [f"  {line}" for line in [*res.lost, *res.twice, *res.tracebacks]]
    return lines
