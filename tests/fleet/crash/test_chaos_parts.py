"""The cheap parts of ``fleet chaos`` (the runs themselves are in ``test_chaos.py``, ``scale``):
the fleet time it counts across restarts of the fleet's clock, the collisions it sums across
restarts of the simulator, the lowest battery it judges, and its refusal of bad keys and bad
``--kill`` kinds before it starts anything."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from fleet.bus.keyring import init_keyring
from fleet.chaos.run import MIN_BATTERY, ChaosResult, ChaosSpec, report_lines, write_timeline
from fleet.chaos.watch import TIMELINE_EVERY_S, Watch
from fleet.cli.main import main
from fleet.messages import StatusRecord

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


def status(
    robot: str, t: float, collisions: int = 0, battery: float = 0.9, mode: str = "patrol"
) -> StatusRecord:
    return StatusRecord(
        robot=robot, ns=f"/{robot}", t=t, pose=(1.0, 2.0, 0.0), battery=battery, charging=False, stuck=False,
        bt="RUNNING", leaf="", mode=mode, task_id="p-0001", laps=0, progress=0.0, distance_m=t,
        collisions=collisions, seq=int(t),
    )  # fmt: skip


def test_fleet_time_and_collisions_add_up_across_restarts() -> None:
    w = Watch()
    for t in (10.0, 20.0, 30.0):
        w.on_status(status("robot1", t, collisions=1))
        w.on_status(status("robot2", t - 0.1))  # another robot a step behind: no time lost or added
    assert w.fleet_elapsed() == pytest.approx(20.0)
    for t in (0.0, 15.0):  # `fleet run` started again: its clock and its collision counts from 0
        w.on_status(status("robot1", t, collisions=0 if t == 0.0 else 2))
    assert w.fleet_elapsed() == pytest.approx(35.0)
    assert sum(w.collisions.values()) == 3


def test_bad_keys_are_refused_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["chaos", str(PATROL), "--robots", "2", "--out", str(tmp_path / "out")]
    assert main([*args, "--secure", str(tmp_path / "missing")]) == 2
    assert f"--secure {tmp_path / 'missing'}: no such key directory" in capsys.readouterr().err
    keys = tmp_path / "keys"
    init_keyring(keys, ["robot1"], "tcp/127.0.0.1:7447")  # no identity for robot2
    assert main([*args, "--secure", str(keys)]) == 2
    assert f"not identity 'robot2': {keys / 'robot2.json5'} is missing" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_battery_run_flat_fails_the_run(tmp_path: Path) -> None:
    w = Watch()
    # robot1 goes to charge at 20 %, dips below 5 % on the way, then charges
    for i, (battery, mode) in enumerate(
        ((0.5, "patrol"), (0.2, "charging"), (0.04, "charging"), (0.3, "charging"))
    ):
        w.on_status(status("robot1", 100.0 + i * TIMELINE_EVERY_S, battery=battery, mode=mode))
        w.on_status(status("robot2", 100.0 + i * TIMELINE_EVERY_S, battery=0.6))
    assert w.min_battery == (0.04, "robot1")
    assert [round(p.battery, 2) for p in w.timeline["robot1"]] == [0.5, 0.2, 0.04, 0.3]
    w.on_status(msgspec.structs.replace(status("robot3", 200.0, battery=1.0), pose=None))
    assert "robot3" not in w.timeline and w.min_battery == (0.04, "robot1")  # no state: no battery
    spec = ChaosSpec(config=PATROL, robots=2, duration=30.0, endpoint="tcp/127.0.0.1:7447", out=tmp_path)
    assert list(w.crossed) == ["robot1"]  # where and doing what it went below 5 %
    at, began = w.crossed["robot1"]
    assert (at.t, at.battery, at.mode) == (20.0, 0.04, "charging")
    assert began is not None and (began.t, began.battery) == (10.0, 0.2)
    timeline = {r: list(x) for r, x in w.timeline.items()}
    res = ChaosResult(spec, min_battery=w.min_battery, timeline=timeline, crossed=w.crossed)
    assert res.flat and not res.ok
    lines = report_lines(res)
    assert f"lowest battery seen: 4.0% (robot1) (below {MIN_BATTERY:.0%}: ran flat)" in lines
    assert (
        "  robot1 below 5% at t=20 s at (1.0, 2.0) m: mode charging, leaf , not on a charger; "
        "in charging mode since t=10 s (10 s), which began at 20% at (1.0, 2.0) m"
    ) in lines
    assert "flat batteries: 1" in lines[-1]
    write_timeline(tmp_path / "battery.csv", res.timeline)
    rows = (tmp_path / "battery.csv").read_text().splitlines()
    assert rows[0] == "robot,t_s,battery,mode,charging,x,y,leaf"
    assert "robot1,20.0,0.0400,charging,0,1.00,2.00," in rows
    ok = ChaosResult(spec, min_battery=(0.06, "robot2"))
    assert ok.ok and "(at least 5%)" in report_lines(ok)[-2]


def test_bad_kill_kinds_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["chaos", str(PATROL), "--robots", "2", "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as e:
        main([*args, "--kill", "sim,router"])
    assert e.value.code == 2
    assert "expected a comma-separated list of sim, coordinator, agent, run; got 'sim,router'" in (
        capsys.readouterr().err
    )
    assert main([*args, "--kill", "sim", "--mode", "run"]) == 2
    assert "--kill sim: --mode run has only the run process to kill" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
