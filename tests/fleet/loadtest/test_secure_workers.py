"""``fleet loadtest --secure DIR``: the main process hosts a secured router, its workers connect
as the key directory's ``worker`` identity, and the router lets that identity do the lockstep
protocol and publish its robots' statuses and liveliness, nothing else. Real worker processes,
real Zenoh with authentication and access control on loopback."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest
import zenoh
from ports import free_endpoint

from fleet.bus.keyring import init_keyring
from fleet.bus.session import Secure, open_session
from fleet.cli.loadtest import loadtest_main
from fleet.loadtest.lockstep import done_key, nav_key, spec_key, tick_key
from fleet.loadtest.run import run_loadtest

#: Hang guard of the waits on the bus (wall s).
WAIT_S = 30.0


def _outcome(data: dict[str, Any]) -> dict[str, Any]:
    keys = ("laps_completed", "collisions", "deadlocks", "patrols_assigned", "reassignments", "sim_time_s")
    return {
        "fleet": {k: data[k] for k in keys},
        "robots": sorted(
            (r["name"], r["distance_m"], r["battery_final"], r["laps"]) for r in data["per_robot"]
        ),
    }


def test_secured_workers_make_the_same_run_as_one_open_process(tmp_path: Path) -> None:
    """4 robots, 120 simulated s, 2 workers on a secured bus: every lockstep message passes
    the router's access control (else the workers would never be ready) and the run is the
    same, laps, collisions and per-robot distances, as the open in-process run."""
    keys = tmp_path / "keys"
    init_keyring(keys, ["robot1"], "tcp/127.0.0.1:7447")  # the robots' own identities are not used
    one = run_loadtest(4, 120, out_dir=tmp_path / "one", sample_s=10, ticking="clock")
    two = run_loadtest(4, 120, out_dir=tmp_path / "two", sample_s=10, workers=2, secure=keys)
    assert not one.interrupted and not two.interrupted
    assert two.data["loadtest"]["workers"] == 2
    assert one.data["laps_completed"] > 0
    assert _outcome(two.data) == _outcome(one.data)


def test_a_bad_secure_path_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["--robots", "2", "--duration", "10", "--out", str(tmp_path / "out")]
    assert loadtest_main([*base, "--secure", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err
    assert f"--secure {tmp_path / 'missing'}: no such key directory" in err and "fleet keys init" in err
    plain = tmp_path / "plain"
    plain.mkdir()
    assert loadtest_main([*base, "--secure", str(plain)]) == 2
    assert f"{plain / 'router.json5'} is missing" in capsys.readouterr().err
    keys = tmp_path / "keys"  # keys made before load-test workers existed: no worker identity
    init_keyring(keys, ["robot1"], "tcp/127.0.0.1:7447")
    (keys / "worker.json5").unlink()
    assert loadtest_main([*base, "--workers", "2", "--secure", str(keys)]) == 2
    err = capsys.readouterr().err
    assert f"not identity 'worker': {keys / 'worker.json5'} is missing" in err and "--force" in err
    assert not (tmp_path / "out" / "report.json").exists()  # refused before anything ran


def test_a_worker_given_a_bad_secure_path_exits_2_before_connecting(tmp_path: Path) -> None:
    """The worker process itself (as a user on another host starts it): a path that is no
    key directory is bad usage, exit 2 with the path named, like every ``fleet`` command;
    nothing is tried on the endpoint (a closed port here)."""
    missing = tmp_path / "missing"
    cmd = [sys.executable, "-m", "fleet.loadtest.worker", "--endpoint", "tcp/127.0.0.1:9", "--index", "0"]
    root = Path(__file__).resolve().parents[3]
    p = subprocess.run(
        [*cmd, "--secure", str(missing)], capture_output=True, text=True, timeout=120, cwd=root
    )
    assert p.returncode == 2, p.stderr
    assert f"fleet loadtest worker 0: --secure {missing}: no such key directory" in p.stderr
    assert "Traceback" not in p.stderr


def test_the_worker_identity_may_do_the_lockstep_and_nothing_more(tmp_path: Path) -> None:
    ep = free_endpoint()
    keys = tmp_path / "keys"
    init_keyring(keys, ["robot1", "robot2"], ep)
    got: list[str] = []
    seen = threading.Condition()

    def note(s: zenoh.Sample) -> None:
        with seen:
            got.append(str(s.key_expr))
            seen.notify_all()

    def wait_for(key: str) -> None:
        with seen:
            assert seen.wait_for(lambda: key in got, WAIT_S), f"{key} never arrived: {got}"

    with open_session(ep, "router", secure=Secure(keys, "router")) as main:
        for k in (done_key("main", 0), "fleet/*/status", "fleet/*/task", "fleet/*/grant", "fleet/*/nav/*",
                  "fleet/sim/clock", "fleet/control/state"):  # fmt: skip
            main.declare_subscriber(k, note)
        main.declare_queryable(spec_key("main"), lambda q: q.reply(q.key_expr, b"spec"))
        main.declare_queryable(nav_key("main"), lambda q: q.reply(q.key_expr, b"nav"))
        with (
            open_session(ep, "client", secure=Secure(keys, "worker")) as worker,
            open_session(ep, "client", secure=Secure(keys, "robot1")) as robot,
        ):
            ticks: list[bytes] = []

            def tick(s: zenoh.Sample) -> None:
                with seen:
                    ticks.append(s.payload.to_bytes())
                    seen.notify_all()

            worker.declare_subscriber(tick_key("main", 0), tick)
            assert [
                r.ok.payload.to_bytes() for r in worker.get(spec_key("main"), timeout=WAIT_S) if r.ok
            ] == [b"spec"]
            assert [r.ok.payload.to_bytes() for r in worker.get(nav_key("main"), timeout=WAIT_S) if r.ok] == [
                b"nav"
            ]
            assert not [r for r in robot.get(spec_key("main"), timeout=2.0) if r.ok]  # a robot may not
            for k in ("fleet/robot1/task", "fleet/robot2/grant", "fleet/robot1/nav/goal", "fleet/sim/clock",
                      "fleet/control/state"):  # fmt: skip
                worker.put(k, b"{}")  # not the worker's to send: dropped by the router
            robot.put(done_key("main", 0), b"forged")  # nor a robot's
            worker.put(done_key("main", 0), b"done")
            worker.put("fleet/robot2/status", b"{}")  # the statuses of the robots it runs
            wait_for("fleet/robot2/status")
            wait_for(done_key("main", 0))
            main.put(tick_key("main", 0), b"tick")
            with seen:
                seen.wait_for(lambda: bool(ticks), WAIT_S)
            assert ticks == [b"tick"]
            assert got.count(done_key("main", 0)) == 1  # the worker's; the robot's forgery dropped
            assert sorted(set(got)) == sorted({done_key("main", 0), "fleet/robot2/status"}), got
