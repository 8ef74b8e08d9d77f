"""The cheap parts of ``fleet chaos`` (the runs themselves are in ``test_chaos.py``, ``scale``):
the fleet time it counts across restarts of the fleet's clock, the collisions it sums across
restarts of the simulator, and its refusal of bad keys before it starts anything."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.bus.keyring import init_keyring
from fleet.chaos.watch import Watch
from fleet.cli.main import main
from fleet.messages import StatusRecord

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"


def status(robot: str, t: float, collisions: int = 0) -> StatusRecord:
    return StatusRecord(
        robot=robot, ns=f"/{robot}", t=t, pose=(1.0, 2.0, 0.0), battery=0.9, charging=False, stuck=False,
        bt="RUNNING", leaf="", mode="patrol", task_id="p-0001", laps=0, progress=0.0, distance_m=t,
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
