"""The fleet-outcome table of docs/performance.md (issue 13, target 6): long runs at several
fleet sizes with traffic management, without it, and on SUMO as the comparison.

For every robot count it runs, one after the other, each a ``fleet`` subprocess at
``--speed 0`` on its own loopback port:

* ``sim``, traffic on: the kinematic simulator with reservation-based traffic management;
* ``sim``, traffic off: the same fleet driving its routes unreserved;
* ``sumo``, traffic off: the same fleet on SUMO (libsumo), whose own car-following and junction
  model keeps vehicles apart; a vehicle SUMO moves on after it waited too long (a *teleport*)
  is its deadlock.

Sizes 6 and 30 are the shipped configs (``fleet run configs/warehouse_patrol*.yaml``); every
other size is ``fleet loadtest``'s generated warehouse for that many robots (every robot on a
patrol loop). The three runs of a size load the same world: the same config file or the same
generated warehouse (same seed), the same robots and start poses, the same coordinator handing
out the same patrol routes; SUMO drives them on a network converted from that roadmap (a lane
per direction on every roadmap edge). The script checks this: it fingerprints the config and
map each run loaded (SHA-256) and the routes it patrolled, and says so under the rows.

Every figure comes from the run's own JSON report (:mod:`fleet.runtime.report`), computed the
same way for every backend:

* ``laps/robot-h``: laps completed / (robots x simulated hours);
* ``mean wait`` / ``p95 wait``: time waiting for right of way per robot (traffic management only:
  the reservations are what robots wait for);
* ``stopped``: simulated seconds per robot that drove, in a driving mode but slower than
  0.1 m/s (sampled every 5 s; load tests only): the wait measure every backend shares;
* ``idle``: share of agent ticks with no work; ``min battery``: lowest battery any robot reported;
  ``below 5 %``: robots whose lowest battery was under 5 %;
* ``deadlocks``: with traffic management, wait-for cycles that lasted (episodes); without it,
  times a robot was reported stuck beside another robot; on SUMO, its teleports.

Progress: a line on stderr every ``--progress-s`` wall seconds of a long run (the run's own
progress line), and each row on stdout as soon as its run ends. ``--wall-limit`` stops a run
after so many wall seconds (SIGINT: the fleet writes the report of what it ran); its row then
shows the simulated seconds it reached.

    python bench/outcome_table.py                                   # 6, 30, 100 robots, 1800 s
    python bench/outcome_table.py --sizes 1000 --duration 1800 --keep /tmp/table
    python bench/outcome_table.py --sizes 5000 --duration 1800 --wall-limit 1800
    python bench/outcome_table.py --sizes 2 --duration 20           # a quick look
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = {6: "configs/warehouse_patrol.yaml", 30: "configs/warehouse_patrol_30.yaml"}
COLUMNS = (
    "robots",
    "simulated s",
    "backend",
    "traffic",
    "laps",
    "laps/robot-h",
    "mean wait s",
    "p95 wait s",
    "stopped s",
    "idle",
    "min battery",
    "below 5 %",
    "collisions",
    "deadlocks",
    "wall s",
)
#: A robot whose lowest battery went under this ran flat (issue 13, target 3).
FLAT = 0.05


@dataclass(frozen=True)
class Run:
    """One run of the table: ``robots`` on ``backend``, traffic management on or off, for
    ``duration`` simulated seconds."""

    robots: int
    backend: str
    traffic: bool
    duration: float
    seed: int = 1

    @property
    def label(self) -> str:
        return f"{self.robots}-{self.backend}-{'on' if self.traffic else 'off'}-{self.duration:g}s"

    def fleet_args(self) -> list[str]:
        """The ``fleet`` arguments of this run (report, endpoint and output options come later)."""
        flag = "--traffic" if self.traffic else "--no-traffic"
        common = ["--backend", self.backend, "--duration", f"{self.duration:g}", flag]
        if self.robots in SHIPPED:
            return ["run", SHIPPED[self.robots], *common, "--speed", "0", "--no-live"]
        return ["loadtest", "--robots", str(self.robots), *common, "--seed", str(self.seed)]


@dataclass
class Outcome:
    """What one run left: its report, the wall seconds it took and the exit code."""

    run: Run
    report: dict[str, Any]
    wall_s: float
    returncode: int
    world: str  # fingerprint of the config and map files the run loaded

    def cells(self) -> dict[str, float | int | str | None]:
        """The table's figures (see the module docstring), ``None`` where a run has none."""
        r = self.report
        sim_s = float(r["sim_time_s"])
        n = int(r["robots"])
        hours = n * sim_s / 3600.0
        lt = r.get("loadtest") or {}
        batteries = [float(p.get("battery_min", p["battery_final"])) for p in r["per_robot"]]
        sumo = self.run.backend == "sumo"
        return {
            "robots": n,
            "simulated s": round(sim_s),
            "backend": self.run.backend,
            "traffic": "on" if self.run.traffic else "off",
            "laps": int(r["laps_completed"]),
            "laps/robot-h": int(r["laps_completed"]) / hours if hours > 0 else None,
            "mean wait s": r.get("mean_wait_s"),
            "p95 wait s": r.get("p95_wait_s"),
            "stopped s": lt.get("mean_wait_s"),
            "idle": float(r.get("idle_fraction", 0.0)),
            "min battery": float(r["min_battery"]),
            "below 5 %": sum(1 for b in batteries if b < FLAT),
            "collisions": int(r["collisions"]),
            "deadlocks": int(r["teleports"] or 0) if sumo else int(r["deadlocks"]),
            "wall s": self.wall_s,
        }


FORMATS = {
    "laps/robot-h": ".2f",
    "mean wait s": ".0f",
    "p95 wait s": ".0f",
    "stopped s": ".0f",
    "idle": ".0%",
    "min battery": ".1%",
    "wall s": ".0f",
}


def header() -> str:
    """The table's header and separator lines."""
    return "| " + " | ".join(COLUMNS) + " |\n|" + "---|" * len(COLUMNS)


def row(o: Outcome) -> str:
    """One Markdown row of the table."""
    out = []
    for col, v in o.cells().items():
        if v is None:
            out.append("–")
        elif col == "deadlocks" and o.run.backend == "sumo":
            out.append(f"{v} teleports")
        elif col == "simulated s" and o.returncode != 0:
            out.append(f"{v} (stopped)")
        else:
            out.append(format(v, FORMATS.get(col, "")))
    return "| " + " | ".join(out) + " |"


def parse_row(line: str) -> dict[str, str]:
    """The cells of a row printed by :func:`row`, by column name."""
    cells = [c.strip() for c in line.strip().strip("|").split("|")]
    if len(cells) != len(COLUMNS):
        raise ValueError(f"expected {len(COLUMNS)} cells, got {len(cells)}: {line!r}")
    return dict(zip(COLUMNS, cells, strict=True))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def world_fingerprint(config: Path) -> str:
    """SHA-256 (first 12 hex digits) of a config file, its occupancy map's YAML and the map's
    image: equal for runs that loaded the same warehouse."""
    import yaml

    h = hashlib.sha256(config.read_bytes())
    map_ref = (yaml.safe_load(config.read_text()) or {}).get("map")
    if isinstance(map_ref, str):
        map_yaml = config.parent / map_ref
        h.update(map_yaml.read_bytes())
        image = (yaml.safe_load(map_yaml.read_text()) or {}).get("image")
        if isinstance(image, str):
            h.update((map_yaml.parent / image).read_bytes())
    return h.hexdigest()[:12]


class _Relay:
    """Keeps a run's newest progress line and passes one on every ``every_s`` wall seconds."""

    def __init__(self, label: str, every_s: float, out: Callable[[str], None]) -> None:
        self.label, self.every_s, self.out = label, every_s, out
        self.last = ""
        self.t_shown = time.monotonic()

    def line(self, text: str) -> None:
        if text.startswith("[") or text.startswith("fleet loadtest: setup"):
            self.last = text.strip()
        if self.last and time.monotonic() - self.t_shown >= self.every_s:
            self.out(f"# {self.label}: {self.last}")
            self.t_shown = time.monotonic()


# long: the subprocess, its log, the progress relay and the wall limit in one place
def run_one(
    run: Run,
    work: Path,
    *,
    wall_limit_s: float | None = None,
    progress_s: float = 60.0,
    out: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True),
) -> Outcome:
    """Run ``run`` with its report, log and outputs under ``work``; stop it with SIGINT after
    ``wall_limit_s`` wall seconds (the fleet then writes the report of what it ran). Raises
    :class:`RuntimeError` when the run failed without a report."""
    work.mkdir(parents=True, exist_ok=True)
    report = work / f"{run.label}.json"
    report.unlink(missing_ok=True)
    extra = ["--report", str(report), "--endpoint", f"tcp/127.0.0.1:{_free_port()}"]
    if run.robots in SHIPPED:
        extra += ["--state", str(work / f"{run.label}-state")]
    else:
        extra += ["--out", str(work / f"{run.label}-floor")]
    cmd = [sys.executable, "-m", "fleet.cli", *run.fleet_args(), *extra]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    relay = _Relay(run.label, progress_s, out)
    log = work / f"{run.label}.log"
    t0 = time.monotonic()
    with log.open("w") as lf:
        lf.write(" ".join(cmd) + "\n")
        proc = subprocess.Popen(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        timer = None
        if wall_limit_s is not None:
            timer = threading.Timer(wall_limit_s, lambda: proc.send_signal(signal.SIGINT))
            timer.daemon = True
            timer.start()
        assert proc.stdout is not None
        for text in proc.stdout:
            lf.write(text)
            lf.flush()
            relay.line(text)
        rc = proc.wait()
        if timer is not None:
            timer.cancel()
    wall = time.monotonic() - t0
    if not report.exists():
        tail = log.read_text()[-2000:]
        raise RuntimeError(f"{' '.join(cmd)} exited {rc} without a report; log {log}:\n{tail}")
    data = dict(json.loads(report.read_text()))
    return Outcome(run, data, wall, rc, world_fingerprint(Path(data["config"])))


def first_loops(report: dict[str, Any]) -> dict[str, str]:
    """``{robot: loop}`` of the patrols the coordinator handed out in the first simulated
    second (a load test's route copies ``<route>_c2``, ... are the same loop as ``<route>``;
    empty when the report's bounded assignment list no longer holds them)."""
    out: dict[str, str] = {}
    for a in report.get("assignments", []):
        if float(a["t_assigned"]) < 1.0:
            out.setdefault(str(a["robot"]), re.sub(r"_c\d+$", "", str(a["route"])))
    return out


def same_world(outcomes: Sequence[Outcome]) -> str:
    """A line saying whether the runs of one size loaded the same world (config and map
    fingerprint), had the same routes, and gave each robot the same first loop (SUMO starts
    its vehicles on the lane point nearest each start pose, so the coordinator's costs, and
    which robot takes which loop, can differ there)."""
    worlds = {o.world for o in outcomes}
    routes = {frozenset(o.report.get("laps_by_route", {})) for o in outcomes}
    n = outcomes[0].run.robots
    first = [first_loops(o.report) for o in outcomes]
    same = sum(1 for robot, route in first[0].items() if all(f.get(robot) == route for f in first[1:]))
    text = f"# {n} robots: " + (
        f"all {len(outcomes)} runs loaded the same world (config and map sha256 {next(iter(worlds))})"
        if len(worlds) == 1
        else f"WORLDS DIFFER ({', '.join(sorted(worlds))})"
    )
    text += f", {'the same' if len(routes) == 1 else 'DIFFERENT'} {len(next(iter(routes)))} routes"
    if first[0]:
        text += f"; {same} of {len(first[0])} robots were given the same first loop in every run"
    return text


#: The runs of each size, in order: (name, backend, traffic management).
KINDS = {"sim-on": ("sim", True), "sim-off": ("sim", False), "sumo-off": ("sumo", False)}


def runs_of(
    sizes: Sequence[int], duration: float, per_size: dict[int, float], kinds: Sequence[str], seed: int
) -> list[Run]:
    """The runs of the table in order: per size the ``kinds`` (names of :data:`KINDS`)."""
    out = []
    for n in sizes:
        d = per_size.get(n, duration)
        out += [Run(n, *KINDS[k], d, seed) for k in KINDS if k in kinds]
    return out


def _durations(items: Sequence[str]) -> dict[int, float]:
    """``["1000=600", ...]`` as ``{1000: 600.0}``."""
    out = {}
    for item in items:
        n, _, d = item.partition("=")
        if not d:
            raise SystemExit(f"--duration-at: expected ROBOTS=SECONDS, got {item!r}")
        out[int(n)] = float(d)
    return out


def _preamble() -> str:
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return f"# commit {commit}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average {load}"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--sizes", type=int, nargs="+", default=[6, 30, 100], help="robot counts (default 6 30 100)"
    )
    ap.add_argument("--duration", type=float, default=1800.0, help="simulated seconds per run (default 1800)")
    ap.add_argument(
        "--duration-at",
        nargs="+",
        default=[],
        metavar="N=S",
        help="another duration for a size, e.g. 5000=300",
    )
    ap.add_argument("--no-sumo", action="store_true", help="leave out the SUMO runs")
    ap.add_argument(
        "--kinds",
        nargs="+",
        choices=list(KINDS),
        default=list(KINDS),
        help="which runs of each size (default all three: sim-on sim-off sumo-off)",
    )
    ap.add_argument("--seed", type=int, default=1, help="seed of the generated warehouses (default 1)")
    ap.add_argument("--wall-limit", type=float, help="stop a run after this many wall seconds (SIGINT)")
    ap.add_argument("--progress-s", type=float, default=60.0, help="wall seconds between progress lines")
    ap.add_argument("--keep", type=Path, help="keep every run's report, log and floor in this directory")
    ap.add_argument("--json", type=Path, help="also write every row's figures here as JSON")
    args = ap.parse_args(argv)
    per_size = _durations(args.duration_at)
    print(_preamble(), flush=True)
    print(header(), flush=True)
    tmp = None if args.keep else tempfile.TemporaryDirectory(prefix="outcome_table_")
    work = args.keep if args.keep else Path(tmp.name)  # type: ignore[union-attr]
    done: list[Outcome] = []
    notes: list[str] = []
    try:
        kinds = [k for k in args.kinds if not (args.no_sumo and k == "sumo-off")]
        runs = runs_of(args.sizes, args.duration, per_size, kinds, args.seed)
        for i, run in enumerate(runs):
            print(f"# run {i + 1}/{len(runs)}: {run.label} started", file=sys.stderr, flush=True)
            o = run_one(run, work, wall_limit_s=args.wall_limit, progress_s=args.progress_s)
            done.append(o)
            print(row(o), flush=True)
            of_size = [d for d in done if d.run.robots == run.robots]
            if i + 1 == len(runs) or runs[i + 1].robots != run.robots:
                notes.append(same_world(of_size))
        for note in notes:
            print(note, flush=True)
        if args.json:
            args.json.write_text(json.dumps([{"label": o.run.label, **o.cells()} for o in done], indent=1))
    finally:
        if tmp is not None:
            tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
