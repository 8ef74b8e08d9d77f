"""JSON encoding of the shared value types of :mod:`fleet.types` (poses, goals, goal states,
feedback, robot states), used on the Zenoh bus.

Every ``*_from_dict`` validates strictly and raises :class:`ValueError` whose message names
the offending field (``goal.pose: expected [x, y, theta] of 3 finite numbers``). Numbers
must be finite; a JSON integer is accepted where a float is expected, a boolean never is.
Poses travel as ``[x, y, theta]`` (``map`` frame, meters, radians).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from fleet.types import (
    BackUp,
    DriveOnHeading,
    Feedback,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    RobotState,
    Spin,
    Wait,
)

# -- field readers (each raises ValueError naming ``path``) -------------------------------


def req(d: Mapping[str, Any], key: str, path: str) -> Any:
    """``d[key]`` or ValueError ``<path>.<key>: missing``."""
    if key not in d:
        raise ValueError(f"{_join(path, key)}: missing")
    return d[key]


def as_float(value: Any, path: str) -> float:
    """A finite number (int or float, not bool) as float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{path}: expected a number, got {type(value).__name__}")
    f = float(value)
    if not math.isfinite(f):
        raise ValueError(f"{path}: expected a finite number, got {value!r}")
    return f


def as_int(value: Any, path: str, *, minimum: int | None = None) -> int:
    """An integer (not bool), optionally ``>= minimum``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{path}: expected an integer, got {type(value).__name__}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{path}: must be >= {minimum}, got {value}")
    return value


def as_bool(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{path}: expected true or false, got {type(value).__name__}")
    return value


def as_str(value: Any, path: str, *, max_len: int = 256) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{path}: expected a string, got {type(value).__name__}")
    if len(value) > max_len:
        raise ValueError(f"{path}: string longer than {max_len} characters")
    return value


def as_opt_str(value: Any, path: str, *, max_len: int = 256) -> str | None:
    return None if value is None else as_str(value, path, max_len=max_len)


def as_dict(value: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(value).__name__}")
    return value


def pose_to_list(p: Pose2D) -> list[float]:
    """``[x, y, theta]``."""
    return [float(p.x), float(p.y), float(p.theta)]


def as_pose(value: Any, path: str) -> Pose2D:
    """A pose from ``[x, y, theta]`` (3 finite numbers)."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"{path}: expected [x, y, theta] of 3 finite numbers")
    x, y, th = (as_float(v, f"{path}[{i}]") for i, v in enumerate(value))
    return Pose2D(x, y, th)


def as_poses(value: Any, path: str, *, max_len: int = 10000) -> tuple[Pose2D, ...]:
    if not isinstance(value, list):
        raise ValueError(f"{path}: expected a list of [x, y, theta], got {type(value).__name__}")
    if len(value) > max_len:
        raise ValueError(f"{path}: more than {max_len} poses")
    return tuple(as_pose(v, f"{path}[{i}]") for i, v in enumerate(value))


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


# -- goals ---------------------------------------------------------------------------------


def goal_to_dict(goal: Goal) -> dict[str, Any]:
    """``{"kind": <Nav2 action name>, ...fields}``; poses as ``[x, y, theta]``.

    Raises ValueError for a non-finite number (JSON cannot carry it) and TypeError for an
    object that is not a goal of :mod:`fleet.types`.
    """
    d: dict[str, Any]
    if isinstance(goal, NavigateToPose):
        d = {"kind": goal.kind, "pose": pose_to_list(goal.pose), "behavior_tree": goal.behavior_tree}
    elif isinstance(goal, NavigateThroughPoses):
        d = {
            "kind": goal.kind,
            "poses": [pose_to_list(p) for p in goal.poses],
            "behavior_tree": goal.behavior_tree,
        }
    elif isinstance(goal, FollowWaypoints):
        d = {"kind": goal.kind, "poses": [pose_to_list(p) for p in goal.poses]}
    elif isinstance(goal, Spin):
        d = {"kind": goal.kind, "target_yaw": goal.target_yaw, "time_allowance_s": goal.time_allowance_s}
    elif isinstance(goal, (BackUp, DriveOnHeading)):
        d = {
            "kind": goal.kind,
            "distance_m": goal.distance_m,
            "speed_mps": goal.speed_mps,
            "time_allowance_s": goal.time_allowance_s,
        }
    elif isinstance(goal, Wait):
        d = {"kind": goal.kind, "duration_s": goal.duration_s}
    else:
        raise TypeError(f"not a navigation goal: {type(goal).__name__}")
    goal_from_dict(d)  # the same strict check as the receiver (finite numbers)
    return d


def goal_from_dict(d: Any, path: str = "goal") -> Goal:
    """The goal encoded by :func:`goal_to_dict`; ValueError naming the bad field."""
    d = as_dict(d, path)
    kind = as_str(req(d, "kind", path), _join(path, "kind"))

    def f(key: str) -> float:
        return as_float(req(d, key, path), _join(path, key))

    def bt() -> str:
        return as_str(d.get("behavior_tree", ""), _join(path, "behavior_tree"), max_len=4096)

    if kind == "navigate_to_pose":
        return NavigateToPose(as_pose(req(d, "pose", path), _join(path, "pose")), behavior_tree=bt())
    if kind == "navigate_through_poses":
        return NavigateThroughPoses(as_poses(req(d, "poses", path), _join(path, "poses")), behavior_tree=bt())
    if kind == "follow_waypoints":
        return FollowWaypoints(as_poses(req(d, "poses", path), _join(path, "poses")))
    if kind == "spin":
        return Spin(f("target_yaw"), time_allowance_s=f("time_allowance_s"))
    if kind == "backup":
        return BackUp(f("distance_m"), speed_mps=f("speed_mps"), time_allowance_s=f("time_allowance_s"))
    if kind == "drive_on_heading":
        return DriveOnHeading(
            f("distance_m"), speed_mps=f("speed_mps"), time_allowance_s=f("time_allowance_s")
        )
    if kind == "wait":
        return Wait(f("duration_s"))
    raise ValueError(f"{_join(path, 'kind')}: unknown goal kind {kind!r}")


# -- feedback, goal states, robot states ---------------------------------------------------

_FB_FLOATS = (
    "navigation_time_s",
    "estimated_time_remaining_s",
    "distance_remaining_m",
    "angular_distance_traveled",
    "distance_traveled",
    "time_left_s",
)
_FB_INTS = ("number_of_recoveries", "number_of_poses_remaining", "current_waypoint")


def feedback_to_dict(fb: Feedback) -> dict[str, Any]:
    """Only the fields that are set (not ``None``); non-finite floats are dropped."""
    d: dict[str, Any] = {}
    if fb.current_pose is not None and all(math.isfinite(v) for v in fb.current_pose.as_tuple()):
        d["current_pose"] = pose_to_list(fb.current_pose)
    for k in _FB_FLOATS:
        v = getattr(fb, k)
        if v is not None and math.isfinite(v):
            d[k] = float(v)
    for k in _FB_INTS:
        v = getattr(fb, k)
        if v is not None:
            d[k] = int(v)
    return d


def feedback_from_dict(d: Any, path: str = "feedback") -> Feedback:
    d = as_dict(d, path)
    kw: dict[str, Any] = {}
    if d.get("current_pose") is not None:
        kw["current_pose"] = as_pose(d["current_pose"], _join(path, "current_pose"))
    for k in _FB_FLOATS:
        if d.get(k) is not None:
            kw[k] = as_float(d[k], _join(path, k))
    for k in _FB_INTS:
        if d.get(k) is not None:
            kw[k] = as_int(d[k], _join(path, k))
    return Feedback(**kw)


def goal_state_to_dict(state: GoalState) -> dict[str, Any]:
    """``goal_id`` is not included: the bridge keys goal states by the client's goal id."""
    d: dict[str, Any] = {
        "kind": state.kind,
        "status": state.status.value,
        "feedback": feedback_to_dict(state.feedback),
        "error_code": int(state.error_code),
        "error_msg": state.error_msg,
    }
    if state.missed_waypoints:
        d["missed_waypoints"] = [int(i) for i in state.missed_waypoints]
    return d


_STATUS_BY_VALUE = {s.value: s for s in GoalStatus}


def goal_state_from_dict(goal_id: str, d: Any, path: str = "goal_state") -> GoalState:
    d = as_dict(d, path)
    status_text = as_str(req(d, "status", path), _join(path, "status"))
    status = _STATUS_BY_VALUE.get(status_text)
    if status is None:
        raise ValueError(f"{_join(path, 'status')}: unknown goal status {status_text!r}")
    missed_raw = d.get("missed_waypoints", [])
    if not isinstance(missed_raw, list):
        raise ValueError(f"{_join(path, 'missed_waypoints')}: expected a list of integers")
    missed = tuple(as_int(v, f"{path}.missed_waypoints[{i}]", minimum=0) for i, v in enumerate(missed_raw))
    return GoalState(
        goal_id=goal_id,
        kind=as_str(req(d, "kind", path), _join(path, "kind")),
        status=status,
        feedback=feedback_from_dict(d.get("feedback", {}), _join(path, "feedback")),
        error_code=as_int(d.get("error_code", 0), _join(path, "error_code"), minimum=0),
        error_msg=as_str(d.get("error_msg", ""), _join(path, "error_msg"), max_len=4096),
        missed_waypoints=missed,
    )


def robot_state_to_dict(st: RobotState) -> dict[str, Any]:
    return {
        "pose": None if st.pose is None else pose_to_list(st.pose),
        "linear_velocity": float(st.linear_velocity),
        "angular_velocity": float(st.angular_velocity),
        "battery": float(st.battery),
        "charging": bool(st.charging),
        "stuck": bool(st.stuck),
        "distance_m": float(st.distance_m),
        "collisions": int(st.collisions),
    }


def robot_state_from_dict(d: Any, path: str = "robot_state") -> RobotState:
    d = as_dict(d, path)
    pose_raw = req(d, "pose", path)

    def f(key: str) -> float:
        return as_float(req(d, key, path), _join(path, key))

    return RobotState(
        pose=None if pose_raw is None else as_pose(pose_raw, _join(path, "pose")),
        linear_velocity=f("linear_velocity"),
        angular_velocity=f("angular_velocity"),
        battery=f("battery"),
        charging=as_bool(req(d, "charging", path), _join(path, "charging")),
        stuck=as_bool(req(d, "stuck", path), _join(path, "stuck")),
        distance_m=f("distance_m"),
        collisions=as_int(req(d, "collisions", path), _join(path, "collisions"), minimum=0),
    )
