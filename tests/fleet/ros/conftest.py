"""Fixtures of the ROS 2 tests: a private ROS domain, an rclpy context for the clients in
this process, and the Nav2 simulator server in a child process.

Every test here is marked ``ros`` and skipped when rclpy or the built nav2_msgs are missing
(``make setup-ros`` provides them).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from fleet.ros.env import apply_ros_env_defaults, ros_available
from fleet.ros.launch import ServerProcess, private_domain_id

ROOT = Path(__file__).resolve().parents[3]
WAREHOUSE = ROOT / "configs" / "warehouse_patrol.yaml"

if not ros_available():
    collect_ignore_glob = ["test_*.py"]
else:
    # Before any rclpy participant exists in this process: a private domain, loopback only,
    # the fast-discovery FastDDS profile. Child processes inherit it.
    os.environ.setdefault("ROS_DOMAIN_ID", str(private_domain_id()))
    apply_ros_env_defaults()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if "tests/fleet/ros/" in str(item.fspath).replace(os.sep, "/"):
            item.add_marker(pytest.mark.ros)


@pytest.fixture(scope="session")
def ros_context() -> Iterator[object]:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    yield ctx
    rclpy.shutdown(context=ctx)


@pytest.fixture(scope="module")
def warehouse_server() -> Iterator[ServerProcess]:
    """The 6-robot warehouse served as namespaced Nav2 at 4x real time."""
    with ServerProcess.for_config(WAREHOUSE, "--speed", "4", "--amcl-hz", "2") as srv:
        yield srv
