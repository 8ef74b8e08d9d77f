"""The ROS environment (``fleet.ros.env``) and what a user without ROS sees: every ROS test
collected and reported as skipped with the reason, never an import error and never silently
gone. These tests need no ROS: they run the ROS tests in a child pytest with ROS disabled
(``FLEET_DISABLE_ROS=1``) and with ROS hidden (its packages made unimportable), and compare
with the list of ROS tests collected normally."""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from fleet.errors import BackendError
from fleet.ros.env import (
    DISCOVERY_PROFILE,
    SCALE_PROFILE,
    apply_ros_env_defaults,
    ros_available,
    ros_unavailable_reason,
)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
#: The ROS packages a machine without ROS lacks (what ``make setup-ros`` installs).
ROS_PACKAGES = (
    "rclpy",
    "nav2_msgs",
    "geographic_msgs",
    "action_msgs",
    "builtin_interfaces",
    "geometry_msgs",
    "lifecycle_msgs",
    "nav_msgs",
    "sensor_msgs",
    "std_msgs",
)
HIDE_ROS_PLUGIN = f"""
import sys
for name in {ROS_PACKAGES!r}:
    sys.modules[name] = None  # import fails, importlib.util.find_spec answers None
"""
#: Hang guard (wall s) of a child pytest that only collects (a few seconds when idle).
CHILD_PYTEST_S = 300


def test_defaults_are_set_only_where_unset() -> None:
    env = apply_ros_env_defaults(7, environ={"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"})
    assert env["RMW_IMPLEMENTATION"] == "rmw_cyclonedds_cpp"
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(DISCOVERY_PROFILE)
    assert env["ROS_DOMAIN_ID"] == "7"
    own = apply_ros_env_defaults(environ={"FASTDDS_DEFAULT_PROFILES_FILE": "/x.xml"})
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in own
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
        apply_ros_env_defaults(300, environ={})


def test_the_scale_profile_differs_only_by_its_longer_lease() -> None:
    """``FLEET_ROS_DISCOVERY=scale`` picks the 20 s-lease profile; the two shipped profiles
    agree on everything else; a wrong value is an error naming the variable."""
    env = apply_ros_env_defaults(environ={"FLEET_ROS_DISCOVERY": "scale"})
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(SCALE_PROFILE)
    with pytest.raises(BackendError, match="FLEET_ROS_DISCOVERY"):
        apply_ros_env_defaults(environ={"FLEET_ROS_DISCOVERY": "fast"})

    def settings(path: Path) -> dict[str, str]:
        root = ET.parse(path).getroot()
        return {
            "/".join(el.tag.split("}")[-1] for el in [*_ancestors(root, leaf), leaf]): (
                leaf.text or ""
            ).strip()
            for leaf in root.iter()
            if len(leaf) == 0
        }

    base, scale = settings(DISCOVERY_PROFILE), settings(SCALE_PROFILE)
    changed = {k for k in base if base[k] != scale.get(k)}
    assert changed == {k for k in base if "leaseDuration/sec" in k}
    assert [scale[k] for k in changed] == ["20"]


@pytest.mark.ros
def test_sim_ros_refuses_a_wrong_discovery_choice_with_one_error_line() -> None:
    env = {**os.environ, "FLEET_ROS_DISCOVERY": "fast", "PYTHONPATH": str(ROOT)}
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    cfg = str(ROOT / "configs" / "warehouse_patrol.yaml")
    out = subprocess.run(
        [sys.executable, "-m", "fleet.cli", "sim-ros", cfg, "--duration", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=CHILD_PYTEST_S,
        cwd=ROOT,
    )
    assert out.returncode == 2, out.stderr
    assert "error: FLEET_ROS_DISCOVERY must be default or scale" in out.stderr
    assert "Traceback" not in out.stderr


def _ancestors(root: ET.Element, leaf: ET.Element) -> list[ET.Element]:
    parents = {c: p for p in root.iter() for c in p}
    chain = []
    while leaf in parents:
        leaf = parents[leaf]
        chain.append(leaf)
    return chain[::-1]


def test_fleet_disable_ros_makes_ros_unavailable() -> None:
    assert ros_unavailable_reason({"FLEET_DISABLE_ROS": "1"}) == "ROS 2 disabled by FLEET_DISABLE_ROS=1"
    assert not ros_available({"FLEET_DISABLE_ROS": "1"})


def _child_pytest(tmp_path: Path, *args: str, env: dict[str, str] | None = None) -> str:
    """Run pytest on the ``ros``-marked tests of this directory in a child process; its
    output (the junit report goes to ``tmp_path / "report.xml"``)."""
    cmd = [
        sys.executable,
        "-m",
        "pytest",
        str(HERE),
        "-m",
        "ros",
        "-p",
        "no:cacheprovider",
        f"--rootdir={ROOT}",
        f"--junitxml={tmp_path / 'report.xml'}",
        *args,
    ]
    full_env = {k: v for k, v in os.environ.items() if k != "FLEET_DISABLE_ROS"} | (env or {})
    out = subprocess.run(
        cmd, cwd=tmp_path, env=full_env, capture_output=True, text=True, timeout=CHILD_PYTEST_S
    )
    assert out.returncode in (0, 5), out.stdout[-3000:] + out.stderr[-3000:]
    return out.stdout


@pytest.fixture(scope="module")
def ros_test_ids(tmp_path_factory: pytest.TempPathFactory) -> set[str]:
    """Node ids of the ``ros`` tests here as collected normally ("file::name[param]"); one
    child collection serves both ways of losing ROS."""
    out = _child_pytest(tmp_path_factory.mktemp("collect"), "--collect-only", "-q")
    ids = {line.split("tests/fleet/ros/", 1)[-1] for line in out.splitlines() if "::" in line}
    assert ids, out
    return ids


def _skipped(tmp_path: Path) -> dict[str, str]:
    """Node id -> skip message of every test case in the child's junit report; fails if a
    test case was not skipped."""
    root = ET.parse(tmp_path / "report.xml").getroot()
    skipped: dict[str, str] = {}
    for case in root.iter("testcase"):
        node = case.find("skipped")
        file = case.get("classname", "").rsplit(".", 1)[-1] + ".py"
        assert node is not None, f"{file}::{case.get('name')} was not skipped"
        skipped[f"{file}::{case.get('name')}"] = node.get("message", "")
    return skipped


@pytest.mark.parametrize(
    ("how", "reason"),
    [
        ("disabled", "ROS 2 disabled by FLEET_DISABLE_ROS=1"),
        ("hidden", "ROS 2 Jazzy (rclpy + nav2_msgs) not installed"),
    ],
    ids=["disabled", "hidden"],
)
def test_ros_tests_are_reported_skipped_with_the_reason_without_ros(
    tmp_path: Path, ros_test_ids: set[str], how: str, reason: str
) -> None:
    expected = ros_test_ids
    if how == "disabled":
        _child_pytest(tmp_path, "-rs", env={"FLEET_DISABLE_ROS": "1"})
    else:
        (tmp_path / "hide_ros.py").write_text(HIDE_ROS_PLUGIN)
        pythonpath = os.pathsep.join(filter(None, [str(tmp_path), str(ROOT), os.environ.get("PYTHONPATH")]))
        _child_pytest(tmp_path, "-rs", "-p", "hide_ros", env={"PYTHONPATH": pythonpath})
    skipped = _skipped(tmp_path)
    assert set(skipped) == expected
    for test, message in skipped.items():
        assert reason in message, f"{test}: {message!r}"
        if how == "hidden":
            assert "make setup-ros" in message
