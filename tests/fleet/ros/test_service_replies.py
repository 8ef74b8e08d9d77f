"""Lifecycle ``get_state`` replies reach every client when several clients start at once.

nav2_simple_commander's ``waitUntilNav2Active`` sends one ``get_state`` request and waits for
the reply with no timeout, so a reply dropped by the middleware hangs a user's script forever.
FastDDS drops a reply when the client's reply reader is not yet discovered within the reply
writer's ``max_blocking_time``; ``fleet/ros/discovery.xml`` raises it for services. Here six
fresh client processes (one per robot) call ``amcl/get_state`` once, at the same moment, and
each must get its reply.
"""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest

pytestmark = pytest.mark.ros

CLIENT = r"""
import sys, time, rclpy
from lifecycle_msgs.srv import GetState
rclpy.init()
node = rclpy.create_node("state_probe", namespace=sys.argv[1])
client = node.create_client(GetState, "amcl/get_state")
if not client.wait_for_service(timeout_sec=60.0):
    print("no-service"); sys.exit(1)
future = client.call_async(GetState.Request())   # one request, like BasicNavigator
deadline = time.monotonic() + 30.0  # a dropped reply never comes
while not future.done() and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print("reply " + future.result().current_state.label if future.done() else "no-reply")
node.destroy_node(); rclpy.shutdown()
"""


def test_simultaneous_clients_all_get_lifecycle_replies(warehouse_server: Any) -> None:
    robots = [f"/robot{i}" for i in range(1, 7)]
    procs = [
        subprocess.Popen([sys.executable, "-c", CLIENT, ns], stdout=subprocess.PIPE, text=True)
        for ns in robots
    ]
    try:
        outputs = {ns: p.communicate(timeout=180)[0].strip() for ns, p in zip(robots, procs, strict=True)}
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert outputs == {ns: "reply active" for ns in robots}
