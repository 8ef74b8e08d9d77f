"""The ``fleet`` command line: help that teaches, one-line errors with exit code 2,
``validate``, and a short ``run`` that writes a complete report and a plot."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from ports import free_endpoint

from fleet.cli.common import EXIT_ERROR
from fleet.cli.main import main
from fleet.runtime.report import REQUIRED_FIELDS, ROBOT_FIELDS

ROOT = Path(__file__).resolve().parents[3]
PATROL = ROOT / "configs" / "warehouse_patrol.yaml"


def test_help_lists_commands_with_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for cmd in ("run", "status", "agent", "coordinator", "sim", "validate"):
        assert cmd in out
    assert "examples:" in out and "fleet run configs/warehouse_patrol.yaml" in out


@pytest.mark.parametrize("cmd", ["run", "agent", "coordinator", "sim", "validate"])
def test_subcommand_help(cmd: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert "example" in capsys.readouterr().out


def test_no_command_prints_help_and_fails(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == EXIT_ERROR
    assert "usage" in capsys.readouterr().out


def test_validate_ok(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate", str(PATROL), "--robots", "8"]) == 0
    out = capsys.readouterr().out
    assert "ok" in out and "robots:      8" in out


def test_bad_config_is_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = yaml.safe_load(PATROL.read_text())
    doc["map"] = str(PATROL.parent / doc["map"])
    doc["robots"][2]["start"] = [4.5, 10.0, 0.0]  # inside a shelf
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc))
    for cmd in (["validate", str(bad)], ["run", str(bad), "--duration", "1"]):
        assert main(cmd) == EXIT_ERROR
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith("error: ") and str(bad) in lines[0] and "robots[2].start" in lines[0]
        assert "Traceback" not in err


def test_missing_config_file(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "no/such/file.yaml"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error: no/such/file.yaml") and "does not exist" in err


def test_bad_option_values_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    for args in (["--speed", "-1"], ["--duration", "0"], ["--robots", "zero"]):
        with pytest.raises(SystemExit) as e:
            main(["run", str(PATROL), *args])
        assert e.value.code == 2
    capsys.readouterr()


def test_unknown_backend_and_agent(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(PATROL), "--duration", "1", "--backend", "nope"]) == EXIT_ERROR
    assert "unknown backend 'nope'" in capsys.readouterr().err
    assert main(["run", str(PATROL), "--duration", "1", "--agents", "robot99"]) == EXIT_ERROR
    assert "robot99" in capsys.readouterr().err


def test_port_in_use_is_a_clean_error(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        code = main(
            [
                "run",
                str(PATROL),
                "--duration",
                "1",
                "--speed",
                "0",
                "--no-live",
                "--endpoint",
                f"tcp/127.0.0.1:{port}",
            ]
        )
    assert code == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1 and str(port) in err


def test_short_run_writes_report_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "out" / "r.json"
    png = tmp_path / "out" / "r.png"
    code = main(
        [
            "run", str(PATROL), "--robots", "3", "--speed", "0", "--duration", "20", "--no-live",
            "--endpoint", free_endpoint(), "--report", str(report), "--plot", str(png),
        ]
    )  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "finished: 3 robots" in out
    data = json.loads(report.read_text())
    for f in REQUIRED_FIELDS:
        assert f in data, f
    assert data["robots"] == 3 and len(data["per_robot"]) == 3
    for row in data["per_robot"]:
        for f in ROBOT_FIELDS:
            assert f in row, f
    assert abs(data["sim_time_s"] - 20.0) < 0.2
    assert data["patrols_assigned"] == 3
    assert png.stat().st_size > 10_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_console_script_help() -> None:
    exe = Path(sys.executable).parent / "fleet"
    res = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and "fleet run" in res.stdout
