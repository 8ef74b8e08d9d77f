"""The executor choice of the fleet's ROS processes (``fleet.ros.executors``): the variable is
read as documented, a bad value is refused naming it, and rclpy's events executor, when picked,
runs a node's timer and subscription callbacks (it serves ``fleet sim-ros`` on request)."""

from __future__ import annotations

import time
from typing import Any

import pytest

pytestmark = pytest.mark.ros


def test_the_variable_picks_the_executor(monkeypatch: pytest.MonkeyPatch, ros_context: Any) -> None:
    from rclpy.executors import SingleThreadedExecutor

    from fleet.ros.executors import DEFAULT, EXECUTOR_VAR, executor_kind, make_executor

    monkeypatch.delenv(EXECUTOR_VAR, raising=False)
    assert executor_kind() == DEFAULT == "single"
    assert isinstance(make_executor(ros_context), SingleThreadedExecutor)
    monkeypatch.setenv(EXECUTOR_VAR, " Events ")
    assert executor_kind() == "events"
    assert not isinstance(make_executor(ros_context), SingleThreadedExecutor)
    monkeypatch.setenv(EXECUTOR_VAR, "multi")
    with pytest.raises(ValueError, match=f"{EXECUTOR_VAR} must be one of single, events, got 'multi'"):
        executor_kind()


def test_events_executor_runs_timers_and_subscriptions(
    monkeypatch: pytest.MonkeyPatch, ros_context: Any
) -> None:
    from rclpy.node import Node
    from std_msgs.msg import String

    from fleet.ros.executors import EXECUTOR_VAR, make_executor

    monkeypatch.setenv(EXECUTOR_VAR, "events")
    node = Node("events_probe", namespace="/events_probe", context=ros_context, enable_rosout=False)
    ex = make_executor(ros_context)
    ex.add_node(node)
    heard: list[str] = []
    ticks: list[int] = []
    pub = node.create_publisher(String, "chatter", 10)
    node.create_subscription(String, "chatter", lambda m: heard.append(m.data), 10)
    node.create_timer(0.05, lambda: (ticks.append(1), pub.publish(String(data=f"tick {len(ticks)}"))))
    try:
        deadline = time.monotonic() + 30.0  # hang guard
        while len(heard) < 3 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.1)
        assert len(ticks) >= 3
        assert heard[:3] == ["tick 1", "tick 2", "tick 3"]
    finally:
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()


def test_sim_ros_refuses_an_unknown_executor_in_one_line() -> None:
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "FLEET_ROS_EXECUTOR": "threads", "PYTHONPATH": str(root)}
    proc = subprocess.run(
        [sys.executable, "-m", "fleet.ros.nav2_server", str(root / "configs" / "warehouse_patrol.yaml")],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,  # hang guard
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == "error: FLEET_ROS_EXECUTOR must be one of single, events, got 'threads'"
