"""JSON encoding of the shared value types of :mod:`fleet.types` (poses, goals, goal states,
feedback, robot states), used on the Zenoh bus.

Every ``*_from_dict`` validates strictly and raises :class:`ValueError` whose message names
the offending field (``goal.pose: expected [x, y, theta] of 3 finite numbers``). Numbers
must be finite; a JSON integer is accepted where a float is expected, a boolean never is.
Poses travel as ``[x, y, theta]`` (``map`` frame, meters, radians)."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

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

if TYPE_CHECKING:
    pass


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


#: Version of the status and task records (field ``v``).
BUS_VERSION = 1


#: Payloads larger than this are dropped as malformed without being parsed.
MAX_PAYLOAD_BYTES = 256 * 1024


_ROBOT_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


TASK_KINDS = ("patrol", "pick", "idle")


def check_robot_name(robot: str) -> str:
    """Return ``robot`` if it can be one key chunk (``robot3``); ValueError otherwise."""
    if not isinstance(robot, str) or not _ROBOT_RE.match(robot):
        raise ValueError(f"robot name {robot!r} cannot be a Zenoh key chunk (use letters, digits, _ . -)")
    return robot


def _decode(data: bytes | bytearray | memoryview | str, what: str) -> dict[str, Any]:
    if isinstance(data, str):
        data = data.encode("utf-8")
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"payload: {len(data)} bytes is larger than {MAX_PAYLOAD_BYTES}")
    try:
        text = bytes(data).decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"payload: not UTF-8 ({e.reason} at byte {e.start})") from None
    try:
        obj = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise ValueError(f"payload: not JSON ({str(e)[:80]})") from None
    d = dict(as_dict(obj, what))
    v = req(d, "v", what)
    if isinstance(v, bool) or v != BUS_VERSION:
        raise ValueError(f"{what}.v: unsupported version {v!r} (expected {BUS_VERSION})")
    return d


def _dumps(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":"), allow_nan=False).encode("utf-8")


@dataclass(frozen=True)
class StatusRecord:
    """One robot's status (``fleet/<robot>/status``); see ``docs/architecture.md``.

    ``t`` is simulated seconds; ``pose`` ``(x, y, theta)`` in the ``map`` frame or ``None``;
    ``battery`` a fraction; ``bt`` the root status name (``RUNNING``...); ``leaf`` the active
    leaf; ``progress`` through the current lap in [0, 1]; ``seq`` increases per record;
    ``picks_done`` picks the robot completed since its agent started (optional on the wire,
    ``0`` when absent).
    """

    robot: str
    ns: str
    t: float
    pose: tuple[float, float, float] | None
    battery: float
    charging: bool
    stuck: bool
    bt: str
    leaf: str
    mode: str
    task_id: str | None
    laps: int
    progress: float
    distance_m: float
    collisions: int
    seq: int
    picks_done: int = 0
    v: int = BUS_VERSION

    def to_dict(self) -> dict[str, Any]:
        # a shallow copy of the fields (all plain values): dataclasses.asdict deep-copies
        # recursively and was half the cost of publishing a status
        d = dict(vars(self))
        d["pose"] = None if self.pose is None else [float(x) for x in self.pose]
        return d

    def to_json(self) -> bytes:
        """UTF-8 JSON; ValueError naming the field if the record itself is invalid."""
        d = self.to_dict()
        StatusRecord.from_dict(d)
        return _dumps(d)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> StatusRecord:
        """Parse and validate; ValueError naming the bad field (``status.battery: ...``)."""
        return cls.from_dict(_decode(data, "status"))

    @classmethod
    def from_dict(cls, d: Any) -> StatusRecord:
        p = "status"
        d = as_dict(d, p)
        v = req(d, "v", p)
        if isinstance(v, bool) or v != BUS_VERSION:
            raise ValueError(f"status.v: unsupported version {v!r} (expected {BUS_VERSION})")
        robot = check_robot_name_field(req(d, "robot", p), "status.robot")
        pose_raw = req(d, "pose", p)
        pose = None if pose_raw is None else as_pose(pose_raw, "status.pose").as_tuple()
        return cls(
            robot=robot,
            ns=as_str(req(d, "ns", p), "status.ns"),
            t=as_float(req(d, "t", p), "status.t"),
            pose=pose,
            battery=as_float(req(d, "battery", p), "status.battery"),
            charging=as_bool(req(d, "charging", p), "status.charging"),
            stuck=as_bool(req(d, "stuck", p), "status.stuck"),
            bt=as_str(req(d, "bt", p), "status.bt"),
            leaf=as_str(req(d, "leaf", p), "status.leaf"),
            mode=as_str(req(d, "mode", p), "status.mode"),
            task_id=as_opt_str(req(d, "task_id", p), "status.task_id"),
            laps=as_int(req(d, "laps", p), "status.laps", minimum=0),
            progress=as_float(req(d, "progress", p), "status.progress"),
            distance_m=as_float(req(d, "distance_m", p), "status.distance_m"),
            collisions=as_int(req(d, "collisions", p), "status.collisions", minimum=0),
            seq=as_int(req(d, "seq", p), "status.seq", minimum=0),
            picks_done=as_int(d.get("picks_done", 0), "status.picks_done", minimum=0),
            v=BUS_VERSION,
        )


def check_robot_name_field(value: Any, path: str) -> str:
    s = as_str(value, path, max_len=128)
    if not _ROBOT_RE.match(s):
        raise ValueError(f"{path}: {s!r} is not a valid robot name")
    return s


@dataclass(frozen=True)
class PickOrder:
    """Pick details of a ``pick`` task: drive to ``shelf``, stand ``dwell_s`` s, drive to ``drop``.

    Any object with ``name``, ``shelf``, ``drop`` and ``dwell_s`` (e.g.
    :class:`fleet.config.PickTask`) can be sent; a received one is a :class:`PickOrder`.
    """

    name: str
    shelf: Pose2D
    drop: Pose2D
    dwell_s: float


@dataclass(frozen=True)
class TaskMessage:
    """An order for one robot (``fleet/<robot>/task``).

    ``kind`` is ``patrol`` (``route`` name and the lap's ``poses``), ``pick`` (``pick`` set) or
    ``idle`` (``task_id`` may be ``None``). ``charger`` is the charger pose to use when low.
    ``robot`` is the addressee (filled from the key on receipt if absent). Task ids are never
    reused.
    """

    task_id: str | None
    kind: str
    robot: str | None = None
    route: str | None = None
    poses: tuple[Pose2D, ...] = ()
    charger: Pose2D | None = None
    pick: Any = None
    v: int = BUS_VERSION

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"v": BUS_VERSION, "task_id": self.task_id, "kind": self.kind}
        if self.robot is not None:
            d["robot"] = self.robot
        if self.route is not None:
            d["route"] = self.route
        if self.poses:
            d["poses"] = [pose_to_list(_to_pose(p)) for p in self.poses]
        if self.charger is not None:
            d["charger"] = pose_to_list(_to_pose(self.charger))
        if self.pick is not None:
            pk = self.pick
            d["pick"] = {
                "name": str(getattr(pk, "name", "")),
                "shelf": pose_to_list(_to_pose(pk.shelf)),
                "drop": pose_to_list(_to_pose(pk.drop)),
                "dwell_s": float(pk.dwell_s),
            }
        return d

    def to_json(self) -> bytes:
        d = self.to_dict()
        TaskMessage.from_dict(d)
        return _dumps(d)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> TaskMessage:
        """Parse and validate; ValueError naming the bad field (``task.poses[2]: ...``)."""
        return cls.from_dict(_decode(data, "task"))

    @classmethod
    def from_dict(cls, d: Any) -> TaskMessage:
        p = "task"
        d = as_dict(d, p)
        v = req(d, "v", p)
        if isinstance(v, bool) or v != BUS_VERSION:
            raise ValueError(f"task.v: unsupported version {v!r} (expected {BUS_VERSION})")
        kind = as_str(req(d, "kind", p), "task.kind")
        if kind not in TASK_KINDS:
            raise ValueError(f"task.kind: {kind!r} is not one of {', '.join(TASK_KINDS)}")
        task_id = as_opt_str(req(d, "task_id", p), "task.task_id")
        if task_id is None and kind != "idle":
            raise ValueError(f"task.task_id: a {kind} task needs an id")
        robot = d.get("robot")
        pick = None
        if d.get("pick") is not None:
            pd = as_dict(d["pick"], "task.pick")
            pick = PickOrder(
                name=as_str(pd.get("name", ""), "task.pick.name"),
                shelf=as_pose(req(pd, "shelf", "task.pick"), "task.pick.shelf"),
                drop=as_pose(req(pd, "drop", "task.pick"), "task.pick.drop"),
                dwell_s=as_float(req(pd, "dwell_s", "task.pick"), "task.pick.dwell_s"),
            )
        if kind == "pick" and pick is None:
            raise ValueError("task.pick: missing (a pick task needs shelf, drop and dwell_s)")
        poses = as_poses(d.get("poses", []), "task.poses")
        if kind == "patrol" and not poses:
            raise ValueError("task.poses: a patrol task needs at least one pose")
        return cls(
            task_id=task_id,
            kind=kind,
            robot=None if robot is None else check_robot_name_field(robot, "task.robot"),
            route=as_opt_str(d.get("route"), "task.route"),
            poses=poses,
            charger=None if d.get("charger") is None else as_pose(d["charger"], "task.charger"),
            pick=pick,
        )


def _to_pose(p: Any) -> Pose2D:
    if isinstance(p, Pose2D):
        return p
    x, y, th = (float(v) for v in p)
    return Pose2D(x, y, th)


@dataclass(frozen=True)
class Grant:
    """What one robot may drive now.

    ``nodes`` / ``poses``: the granted path nodes ahead of the node the robot last reached
    (``current``), in driving order, with poses facing along the path (``map`` frame). Empty
    while the robot must wait (or has no path). ``horizon`` is the absolute index in path
    ``path_id`` of the last granted node: a follower resends a goal when ``(path_id,
    horizon)`` changes. ``final``: the grant reaches the end of the path. ``alive``: false
    once the manager treats the robot as dead (it must not move). ``done``: the robot has
    reached the end of its path. Set by :class:`ReservationTraffic` (the manager leaves the
    defaults): ``task_id`` the coordinator assignment the path serves, ``purpose`` why the
    robot drives (``patrol``, ``charge``, ``charge-wait``, ``park`` or ``""``), ``laps``
    loops completed on the path for ``task_id``, ``seq`` a per-robot counter (a receiver
    ignores a grant whose ``seq`` is not newer than the last one it applied).
    ``JSON``: :meth:`to_dict` / :meth:`from_dict`.
    """

    robot: str
    path_id: int
    horizon: int
    current: str | None
    nodes: tuple[str, ...]
    poses: tuple[Pose2D, ...]
    final: bool = False
    waiting: bool = False
    done: bool = False
    alive: bool = True
    task_id: str | None = None
    purpose: str = ""
    laps: int = 0
    seq: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "v": 1,
            "robot": self.robot,
            "path_id": self.path_id,
            "horizon": self.horizon,
            "current": self.current,
            "nodes": list(self.nodes),
            "poses": [list(p.as_tuple()) for p in self.poses],
            "final": self.final,
            "waiting": self.waiting,
            "done": self.done,
            "alive": self.alive,
            "task_id": self.task_id,
            "purpose": self.purpose,
            "laps": self.laps,
            "seq": self.seq,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Grant:
        return cls(
            robot=str(d["robot"]),
            path_id=int(d["path_id"]),
            horizon=int(d["horizon"]),
            current=None if d.get("current") is None else str(d["current"]),
            nodes=tuple(str(n) for n in d["nodes"]),
            poses=tuple(Pose2D(float(p[0]), float(p[1]), float(p[2])) for p in d["poses"]),
            final=bool(d.get("final", False)),
            waiting=bool(d.get("waiting", False)),
            done=bool(d.get("done", False)),
            alive=bool(d.get("alive", True)),
            task_id=None if d.get("task_id") is None else str(d["task_id"]),
            purpose=str(d.get("purpose", "")),
            laps=int(d.get("laps", 0)),
            seq=int(d.get("seq", 0)),
        )


BRIDGE_VERSION = 1


MAX_BRIDGE_PAYLOAD = 1024 * 1024


def _loads(data: bytes, what: str) -> dict[str, Any]:
    if len(data) > MAX_BRIDGE_PAYLOAD:
        raise ValueError(f"payload: {len(data)} bytes is too large")
    try:
        obj = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ValueError(f"payload: not UTF-8 JSON ({str(e)[:80]})") from None
    d = dict(as_dict(obj, what))
    v = req(d, "v", what)
    if isinstance(v, bool) or v != BRIDGE_VERSION:
        raise ValueError(f"{what}.v: unsupported version {v!r}")
    return d


def _dumps(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":"), allow_nan=False).encode("utf-8")
