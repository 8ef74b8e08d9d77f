"""A robot left at a low battery by an earlier run, idle at the start of this one (never given a
task: it is below the charge threshold), is sent to charge; in-process simulator with the
coordinator (the same run over ROS is in ``tests/fleet/ros/test_ros_ground_truth.py``)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from fleet_procs import temp_config
from ports import free_endpoint

from fleet.config.loader import load_config
from fleet.runtime.runner import FleetRunner


def test_idle_robot_below_the_threshold_charges(tmp_path: Path) -> None:
    def edit(doc: dict[str, Any]) -> None:
        doc["robots"][5]["battery"] = 0.08  # below battery.low (0.25) from the start

    cfg = load_config(temp_config(tmp_path, edit))
    report: Any = FleetRunner(
        cfg, duration=120.0, speed=0, endpoint=free_endpoint(), backend="sim", live=False, out=io.StringIO()
    ).run()
    robot6 = next(r for r in report.per_robot if r.name == "robot6")
    assert robot6.charges >= 1, robot6
    assert robot6.battery_final > 0.08, robot6
