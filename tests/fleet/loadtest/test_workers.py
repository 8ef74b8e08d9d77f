"""``fleet loadtest --workers K``: agents in K worker processes, in lockstep with the main
process (simulator, coordinator, traffic management), make the same run as one process; a
worker that dies ends the run with a report; Ctrl-C leaves no process behind. Real worker
processes, real Zenoh on loopback, the real simulator and trees."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint

from fleet.errors import ConfigError
from fleet.loadtest.distributed import DistributedRunner, assign
from fleet.loadtest.lockstep import RunSpec
from fleet.loadtest.run import prepare_config, run_loadtest
from fleet.viz.display import NullDisplay

#: Hang guard of a whole small run on a loaded 2-core machine (wall s).
RUN_GUARD_S = 240.0


def _outcome(data: dict[str, Any]) -> dict[str, Any]:
    """Everything of a load-test report that is decided by the run (no wall times)."""
    lt = data["loadtest"]
    return {
        "fleet": {k: data[k] for k in ("laps_completed", "collisions", "deadlocks", "patrols_assigned",
                                       "patrols_completed", "reassignments", "sim_time_s")},
        "robots": sorted(
            (r["name"], r["distance_m"], r["battery_final"], r["laps"], r["final_state"]) for r in data["per_robot"]
        ),
        "series": {k: lt["series"][k] for k in ("t_s", "laps", "waiting", "collisions", "deadlocks", "states")},
    }  # fmt: skip


def test_two_workers_make_the_same_run_as_one_process(tmp_path: Path) -> None:
    """16 robots, 5 simulated minutes, traffic management on: the same laps, collisions,
    deadlocks, reassignments, per-robot distances and batteries, and the same sampled series
    as the in-process run, exactly (the lockstep makes timing irrelevant). Workers tick every
    agent every period, so the in-process run it is compared with does too (``ticking="clock"``;
    the event-driven ticking makes the same moves but may see a goal end a period later, which
    shows in the goal metrics)."""
    one = run_loadtest(16, 300, out_dir=tmp_path / "one", sample_s=10, ticking="clock")
    two = run_loadtest(16, 300, out_dir=tmp_path / "two", sample_s=10, workers=2)
    assert not one.interrupted and not two.interrupted
    assert two.data["loadtest"]["workers"] == 2
    a, b = _outcome(one.data), _outcome(two.data)
    assert a["fleet"]["laps_completed"] > 0  # the run did something worth comparing
    assert b == a

    # the agents' statistics came back from the workers, and the goal metrics were kept: the
    # goals sent and failed agree; whether a goal that ended as the next one was sent counts as
    # succeeded or canceled may differ by one (a worker sees the goal's end in the next tick's
    # snapshot), so the ended total is compared, not the split
    def stats(data: dict[str, Any]) -> list[tuple[Any, ...]]:
        return [
            (r["name"], r["battery_min"], r["charges"], r["safety_stops"], r["goals"]["sent"],
             r["goals"]["failed"], r["goals"]["succeeded"] + r["goals"]["canceled"])
            for r in data["per_robot"]
        ]  # fmt: skip

    assert stats(two.data) == stats(one.data)
    assert two.data.get("mode_ticks") == one.data.get("mode_ticks")


def test_assignment_is_contiguous_and_balanced() -> None:
    names = [f"r{i}" for i in range(10)]
    parts = assign(names, 4)
    assert [len(p) for p in parts] == [3, 3, 2, 2] and [n for p in parts for n in p] == names


def _runner(tmp_path: Path, workers: int, duration: float) -> DistributedRunner:
    cfg = prepare_config(8, tmp_path / "wh")
    spec = RunSpec(8, 1, 2.0, 1.0, 2.0, None, None, True, assign([r.name for r in cfg.robots], workers))
    return DistributedRunner(
        cfg, spec, log_dir=tmp_path / "logs", duration=duration, speed=0.0, endpoint=free_endpoint(),
        live=False, display=NullDisplay(),
    )  # fmt: skip


def test_a_worker_that_dies_ends_the_run_with_a_report_and_no_process_left(tmp_path: Path) -> None:
    runner = _runner(tmp_path, 2, 3600.0)
    killed: list[float] = []

    def kill_worker(t: float, r: object) -> None:
        if t >= 20.0 and not killed:
            runner.procs[1].kill()
            killed.append(t)

    runner.observers.append(kill_worker)
    t0 = time.monotonic()
    report = runner.run()
    assert time.monotonic() - t0 < RUN_GUARD_S
    assert killed and report.interrupted
    assert 20.0 <= report.sim_time_s < 3600.0
    assert all(p.poll() is not None for p in runner.procs)  # the survivor was stopped too


def _workers_of(marker: str) -> list[int]:
    """Pids of live processes whose command line contains ``marker``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                state = (d / "stat").read_text().split(") ", 1)[1][0]
            except OSError:
                continue
            if marker in cmd and "fleet.loadtest.worker" in cmd and state != "Z":
                out.append(int(d.name))
    return out


def test_ctrl_c_stops_the_run_and_every_worker(tmp_path: Path) -> None:
    out = tmp_path / "ctrlc"
    cmd = [sys.executable, "-m", "fleet.cli", "loadtest", "--robots", "8", "--duration", "100000",
           "--workers", "2", "--out", str(out), "--endpoint", free_endpoint()]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[3]))
    p = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True
    )
    try:
        assert p.stdout is not None
        end = time.monotonic() + RUN_GUARD_S
        for line in p.stdout:
            if "running" in line:
                break
            assert time.monotonic() < end, "no 'running' line"
        assert len(_workers_of(str(out))) == 2
        os.killpg(p.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole group
        rest, _ = p.communicate(timeout=RUN_GUARD_S)
        assert p.returncode == 130, rest
        assert "interrupted" in rest
        assert _workers_of(str(out)) == []
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def test_bad_worker_counts_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--workers.*more workers \(5\) than robots \(3\)"):
        run_loadtest(3, 10, out_dir=tmp_path / "a", workers=5)
    with pytest.raises(ConfigError, match="--workers.*sim backend"):
        run_loadtest(3, 10, out_dir=tmp_path / "b", workers=2, backend="sumo")
    with pytest.raises(ConfigError, match="--workers"):
        run_loadtest(3, 10, out_dir=tmp_path / "c", workers=2, local_workers=3)
