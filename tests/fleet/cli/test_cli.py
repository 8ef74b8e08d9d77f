"""The ``fleet`` command line: help that teaches, one-line errors with exit code 2,
``validate``, ``--log-level`` / ``FLEET_LOG_LEVEL``, and a short ``run`` that writes a complete
report and a plot."""

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
    for cmd in ("run", "status", "agent", "coordinator", "sim", "sim-ros", "validate", "loadtest"):
        assert f"\n    {cmd} " in out, cmd
    assert "--log-level" in out
    assert "examples:" in out and "fleet run configs/warehouse_patrol.yaml" in out


@pytest.mark.parametrize("cmd", ["run", "agent", "coordinator", "sim", "validate", "status", "loadtest"])
def test_subcommand_help(cmd: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "example" in out and "--log-level" in out


def test_a_command_line_builds_the_same_parser_from_its_module_alone() -> None:
    """``COMMANDS`` names every command of the full parser, and the parser built for one
    command (only its module imported) gives it the same options and help."""
    import argparse

    from fleet.cli.main import COMMANDS, build_parser

    def subparsers(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
        (action,) = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        return dict(action.choices)

    full = subparsers(build_parser())
    assert list(full) == list(COMMANDS)
    for cmd in COMMANDS:
        alone = subparsers(build_parser(cmd))
        assert cmd in alone and alone[cmd].format_help() == full[cmd].format_help(), cmd


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


def test_log_level_before_or_after_the_command_and_from_the_environment(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("FLEET_LOG_LEVEL", raising=False)
    run = ["run", str(PATROL), "--robots", "2", "--speed", "0", "--duration", "2", "--no-live"]
    for argv in (["--log-level", "info", *run], [*run, "--log-level", "INFO"]):
        assert main([*argv, "--endpoint", free_endpoint()]) == 0
        err = capsys.readouterr().err
        assert "info: warehouse_patrol: backend sim ready, 2 agents + coordinator" in err, err
        assert "info: warehouse_patrol: run ended at t=2.0 s" in err
    assert main([*run, "--endpoint", free_endpoint()]) == 0  # default: warnings only
    assert "info:" not in capsys.readouterr().err
    monkeypatch.setenv("FLEET_LOG_LEVEL", "debug")
    assert main([*run, "--endpoint", free_endpoint()]) == 0
    err = capsys.readouterr().err
    assert " info fleet.runtime.runner: warehouse_patrol: backend sim ready" in err  # time and logger name
    assert main(["--log-level", "error", *run, "--endpoint", free_endpoint()]) == 0  # the option wins
    assert "info" not in capsys.readouterr().err


def test_bad_log_levels_exit_2(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--log-level", "loud", "validate", str(PATROL)])
    assert e.value.code == 2 and "unknown level 'loud'" in capsys.readouterr().err
    monkeypatch.setenv("FLEET_LOG_LEVEL", "loud")
    assert main(["validate", str(PATROL)]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.strip() == (
        "error: environment: FLEET_LOG_LEVEL: unknown level 'loud'; one of debug, info, warning, error, critical"
    )


def test_sim_ros_passes_its_arguments_through(capsys: pytest.CaptureFixture[str]) -> None:
    """Without ROS: one error line, exit 2; with it, ``--help`` is the ROS server's own help.
    ``--log-level`` is taken out of the passed-through arguments either way."""
    try:
        import fleet.ros.nav2_server  # noqa: F401

        ros = True
    except ImportError:
        ros = False
    if ros:
        with pytest.raises(SystemExit) as e:
            main(["--log-level", "info", "sim-ros", "--help", "--log-level", "debug"])
        assert e.value.code == 0 and "--speed" in capsys.readouterr().out
    else:
        assert main(["sim-ros", "--log-level", "info", "--help"]) == EXIT_ERROR
        err = capsys.readouterr().err
        assert err.startswith("error: fleet sim-ros needs ROS 2 Jazzy") and len(err.strip().splitlines()) == 1
