"""Fixtures of the ROS 2 tests: a private ROS domain, an rclpy context for the clients in
this process, and the Nav2 simulator server in a child process.

Every test module here that needs ROS is marked ``ros``. When ROS cannot run (rclpy or the
built nav2_msgs missing: ``make setup-ros`` provides them; or ``FLEET_DISABLE_ROS=1``) those
tests are still collected and each is reported as skipped with the reason
(:func:`fleet.ros.env.ros_unavailable_reason`), so the modules import nothing from ROS at
import time. ``wait_until`` is the tests' one way to wait for something to happen.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from fleet.ros.domains import ensure_private_domain
from fleet.ros.env import apply_ros_env_defaults, ros_unavailable_reason
from fleet.ros.launch import ServerProcess

if TYPE_CHECKING:
    from rclpy.context import Context

ROOT = Path(__file__).resolve().parents[3]
WAREHOUSE = ROOT / "configs" / "warehouse_patrol.yaml"
HERE = Path(__file__).resolve().parent

#: Why the ROS tests cannot run here (``None``: they can).
UNAVAILABLE = ros_unavailable_reason()

if UNAVAILABLE is None:
    # Before any rclpy participant exists in this process: a private domain, loopback only,
    # the fast-discovery FastDDS profile. Child processes inherit it.
    # the domain is claimed (fleet.ros.domains) so no other run on this machine uses it
    ensure_private_domain()
    apply_ros_env_defaults()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Skip every ``ros`` test of this directory, with the reason, when ROS cannot run."""
    if UNAVAILABLE is None:
        return
    for item in items:
        if item.path.is_relative_to(HERE) and item.get_closest_marker("ros") is not None:
            item.add_marker(pytest.mark.skip(reason=UNAVAILABLE))


@pytest.fixture(scope="session")
def ros_context() -> Iterator[Context]:
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
