"""The interface packages built from ``interfaces/`` by ``tools/build_interfaces.py``.

* a fresh build (geographic_msgs, into a temporary prefix) succeeds and imports;
* nav2_msgs (built by ``make setup-ros``) round-trips a message through CDR serialization;
* the RIHS01 type hashes of the actions are the pinned ones: a change to a definition (and so
  to the wire format) fails here. ``tools/check_nav2_interfaces.py`` compares the definitions
  with Nav2 Jazzy's sources field for field.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tools"))
import build_interfaces  # noqa: E402

#: RIHS01 hashes of the built types (Nav2 Jazzy definitions, see the module docstring).
PINNED = {
    "nav2_msgs/action/NavigateThroughPoses": "RIHS01_4e680a34fd27772095da6ffdb32ae348adbc3d948248d38cf8d5ca3fc7a3a6c4",
    "nav2_msgs/action/NavigateToPose": "RIHS01_a56dba8a3234a1215e610180dc703ae25bbf406dded8b54887891c9732857eab",
    "nav2_msgs/action/FollowWaypoints": "RIHS01_09e36a19e0374ab692e78b877e3345daa223ca4186b8af90f77939b78c6e6d7b",
    "nav2_msgs/action/Spin": "RIHS01_9fc4653cfb2982465e9ca4e2710f0532de8f6dce77d6a6eada55e4e22273b55c",
    "nav2_msgs/action/BackUp": "RIHS01_28d3ef6f5c43fdb860f960f4be61825e80d3c6fd54a12af77005eb477ad60d50",
    "geographic_msgs/msg/GeoPose": "RIHS01_8052786d7663e225e38926f7d05716046c931572c25e557d4f70dca55b972626",
}


def _venv() -> Path:
    return Path(sys.prefix)


def test_fresh_build_of_an_interface_package(tmp_path: Path) -> None:
    venv = _venv()
    prefix = tmp_path / "prefix"
    build_interfaces.build_package("geographic_msgs", venv, prefix, tmp_path / "build", jobs=2)
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    assert (site / "geographic_msgs" / "msg").is_dir()
    env = dict(os.environ)
    env["PYTHONPATH"] = str(site)
    env["LD_LIBRARY_PATH"] = f"{prefix / 'lib'}:{env.get('LD_LIBRARY_PATH', '')}"
    code = (
        "import geographic_msgs, sys; from geographic_msgs.msg import GeoPose;"
        f"assert geographic_msgs.__file__.startswith({str(prefix)!r}), geographic_msgs.__file__;"
        "from rclpy.serialization import serialize_message, deserialize_message;"
        "m = GeoPose(); m.position.latitude = 48.1;"
        "assert deserialize_message(serialize_message(m), GeoPose).position.latitude == 48.1"
    )
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=60)
    desc = json.loads((prefix / "share" / "geographic_msgs" / "msg" / "GeoPose.json").read_text())
    assert desc["type_hashes"][0]["hash_string"] == PINNED["geographic_msgs/msg/GeoPose"]


def test_nav2_message_round_trip() -> None:
    from nav2_msgs.action import FollowWaypoints, NavigateThroughPoses
    from rclpy.serialization import deserialize_message, serialize_message

    from fleet.ros.conversions import goal_to_msg, msg_to_goal
    from fleet.types import NavigateThroughPoses as NTP
    from fleet.types import Pose2D

    goal = NTP((Pose2D(1.0, 2.0, 0.5), Pose2D(3.0, -1.0, -2.0)), behavior_tree="bt.xml")
    msg = goal_to_msg(goal)
    back = deserialize_message(serialize_message(msg), NavigateThroughPoses.Goal)
    g2 = msg_to_goal("navigate_through_poses", back)
    assert g2.behavior_tree == "bt.xml"
    for a, b in zip(g2.poses, goal.poses, strict=True):
        assert a.x == pytest.approx(b.x) and a.y == pytest.approx(b.y) and a.theta == pytest.approx(b.theta)
    r = FollowWaypoints.Result()
    r.error_code = FollowWaypoints.Result.TASK_EXECUTOR_FAILED
    r.error_msg = "x"
    assert deserialize_message(serialize_message(r), FollowWaypoints.Result).error_code == 601


@pytest.mark.parametrize("type_name", sorted(PINNED))
def test_type_hash_is_stable(type_name: str) -> None:
    pkg, kind, name = type_name.split("/")
    desc = json.loads((_venv() / "share" / pkg / kind / f"{name}.json").read_text())
    assert desc["type_hashes"][0]["type_name"] == type_name
    assert desc["type_hashes"][0]["hash_string"] == PINNED[type_name]


def test_rebuild_is_skipped_when_nothing_changed() -> None:
    out = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "build_interfaces.py"), "--venv", str(_venv())],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    assert "nothing to build" in out or "building nothing" in out
