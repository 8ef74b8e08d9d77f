"""Shared value types of the fleet: poses, navigation goals, goal states, robot state.

Every module of the core (``fleet``, ``nodes``, ``sim``) speaks these types; adapters
(ROS 2, SUMO) translate them at the edge. Units: meters, radians, seconds. Frame: ``map``.

Error codes are Nav2 Jazzy's numeric codes, so a result from the simulator and a result
from a real Nav2 server mean the same thing (see :class:`ErrorCode`).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar


@dataclass(frozen=True)
class Pose2D:
    """A planar pose in the ``map`` frame: ``x``, ``y`` in meters, ``theta`` (yaw) in radians."""

    x: float
    y: float
    theta: float = 0.0

    def distance_to(self, other: Pose2D) -> float:
        """Euclidean distance in meters, ignoring heading."""
        return math.hypot(other.x - self.x, other.y - self.y)

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)


def make_pose(x: float, y: float, theta: float = 0.0) -> Pose2D:
    """``Pose2D(x, y, theta)`` built without the frozen dataclass's ``__init__`` (the very
    instance it would build; a third of its cost): for poses made once per robot per period."""
    pose = _new(Pose2D)
    state = pose.__dict__
    state["x"] = x
    state["y"] = y
    state["theta"] = theta
    return pose


_new = object.__new__


def normalize_angle(a: float) -> float:
    """Wrap an angle in radians to ``[-pi, pi)``."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


# ---------------------------------------------------------------------------
# Goals: one dataclass per Nav2 action. ``kind`` is the Nav2 action server name.
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class NavigateThroughPoses:
    """Drive through ``poses`` in order (Nav2 ``navigate_through_poses``)."""

    poses: tuple[Pose2D, ...]
    behavior_tree: str = ""
    kind: str = field(default="navigate_through_poses", init=False)


@dataclass(frozen=True)
class NavigateToPose:
    """Drive to ``pose`` (Nav2 ``navigate_to_pose``)."""

    pose: Pose2D
    behavior_tree: str = ""
    kind: str = field(default="navigate_to_pose", init=False)


@dataclass(frozen=True)
class FollowWaypoints:
    """Visit each of ``poses``; a missed waypoint is reported, not fatal (Nav2 ``follow_waypoints``)."""

    poses: tuple[Pose2D, ...]
    kind: str = field(default="follow_waypoints", init=False)


@dataclass(frozen=True)
class Spin:
    """Rotate in place by ``target_yaw`` radians (signed) within ``time_allowance_s``."""

    target_yaw: float
    time_allowance_s: float = 10.0
    kind: str = field(default="spin", init=False)


@dataclass(frozen=True)
class BackUp:
    """Drive straight backwards ``distance_m`` (positive) at ``speed_mps`` (positive)."""

    distance_m: float
    speed_mps: float = 0.1
    time_allowance_s: float = 10.0
    kind: str = field(default="backup", init=False)


@dataclass(frozen=True)
class DriveOnHeading:
    """Drive straight forwards ``distance_m`` at ``speed_mps``."""

    distance_m: float
    speed_mps: float = 0.1
    time_allowance_s: float = 10.0
    kind: str = field(default="drive_on_heading", init=False)


@dataclass(frozen=True)
class Wait:
    """Stand still for ``duration_s`` seconds."""

    duration_s: float
    kind: str = field(default="wait", init=False)


#: A path: poses in order (``map`` frame), as Nav2's ``nav_msgs/Path`` carries them.
Path = tuple[Pose2D, ...]


@dataclass(frozen=True)
class FollowPath:
    """Drive along ``path`` with the controller (Nav2 ``follow_path``): the robot follows the
    poses in order and turns to the last pose's yaw. An empty path aborts with
    ``INVALID_PATH``; a robot that stops getting closer aborts with
    ``FAILED_TO_MAKE_PROGRESS``. ``controller_id`` / ``goal_checker_id`` name Nav2 plugins
    (a backend with one controller ignores them)."""

    path: Path
    controller_id: str = ""
    goal_checker_id: str = ""
    kind: str = field(default="follow_path", init=False)


@dataclass(frozen=True)
class ComputePathToPose:
    """Plan a path to ``goal`` (Nav2 ``compute_path_to_pose``) from ``start``, or from the
    robot's pose when ``start`` is ``None``. Moves nothing; the result's
    :attr:`GoalState.path` holds the plan (start to goal, each pose facing the next, the last
    one with the goal's yaw). Fails with the planner codes 2xx."""

    goal: Pose2D
    start: Pose2D | None = None
    planner_id: str = ""
    kind: str = field(default="compute_path_to_pose", init=False)


@dataclass(frozen=True)
class ComputePathThroughPoses:
    """Plan one path through ``goals`` in order (Nav2 ``compute_path_through_poses``) from
    ``start`` or the robot's pose. Moves nothing; the result carries the path. Fails with the
    through-poses codes 3xx (``NO_VIAPOINTS_GIVEN`` for no goals)."""

    goals: Path
    start: Pose2D | None = None
    planner_id: str = ""
    kind: str = field(default="compute_path_through_poses", init=False)


@dataclass(frozen=True)
class SmoothPath:
    """Smooth ``path`` (Nav2 ``smooth_path``): the same start and end, corners rounded where
    the map allows. Moves nothing; the result carries the smoothed path. With
    ``check_for_collisions`` a smoothed path that would touch an obstacle fails with
    ``SMOOTHED_PATH_IN_COLLISION``; an empty path fails with ``SMOOTHER_INVALID_PATH``."""

    path: Path
    smoother_id: str = ""
    max_smoothing_duration_s: float = 3.0
    check_for_collisions: bool = False
    kind: str = field(default="smooth_path", init=False)


class Costmap(enum.StrEnum):
    """Which of a robot's costmaps a :class:`ClearCostmaps` goal clears."""

    GLOBAL = "global"
    LOCAL = "local"
    BOTH = "both"


@dataclass(frozen=True)
class ClearCostmaps:
    """Clear the robot's ``costmap`` (``global``, ``local`` or ``both``) of everything but the
    static map, as Nav2's ``clear_entirely_<global|local>_costmap`` services do. Moves
    nothing; SUCCEEDS once the costmaps are cleared."""

    costmap: Costmap = Costmap.BOTH
    kind: str = field(default="clear_costmaps", init=False)


Goal = (
    NavigateThroughPoses
    | NavigateToPose
    | FollowWaypoints
    | Spin
    | BackUp
    | DriveOnHeading
    | Wait
    | FollowPath
    | ComputePathToPose
    | ComputePathThroughPoses
    | SmoothPath
    | ClearCostmaps
)

NAV_GOAL_KINDS = ("navigate_through_poses", "navigate_to_pose", "follow_waypoints")
#: Goals that move the robot. A robot executes one of these at a time: a new one preempts the
#: one executing (it ends ABORTED).
MOTION_GOAL_KINDS = (
    "navigate_through_poses",
    "navigate_to_pose",
    "follow_waypoints",
    "spin",
    "backup",
    "drive_on_heading",
    "wait",
    "follow_path",
)
#: Goals that compute (plan, smooth, clear costmaps) without moving the robot: Nav2's planner,
#: smoother and costmap servers run beside the controller, so these neither preempt the
#: robot's motion goal nor are preempted by it (any number may be outstanding).
COMPUTE_GOAL_KINDS = ("compute_path_to_pose", "compute_path_through_poses", "smooth_path", "clear_costmaps")


# ---------------------------------------------------------------------------
# Modes and kinds. String enums: each member equals its value (``Mode.PATROL == "patrol"``),
# so they travel on the wire and in reports as plain strings.
# ---------------------------------------------------------------------------


class Mode(enum.StrEnum):
    """What a robot's behavior tree is doing, as it reports in its status (``mode``)."""

    IDLE = "idle"
    PATROL = "patrol"
    PICKING = "picking"
    CHARGING = "charging"
    RECOVERY = "recovery"
    #: The safety watchdog stopped the robot (localization lost, navigation server down).
    SAFETY_STOP = "safety_stop"
    #: driving or acting on a go_to, inspection or park task (``nodes/steps.py``)
    TASK = "task"
    #: the fleet is paused: the tree is stopped, the robot stands, its task is kept
    PAUSED = "paused"
    #: the fleet's emergency stop is latched: nothing moves until it is released
    ESTOP = "estop"


#: Modes in which a robot is expected to drive (the coordinator's stuck check).
DRIVING_MODES: frozenset[Mode] = frozenset({Mode.PATROL, Mode.PICKING, Mode.RECOVERY, Mode.TASK})


class TaskKind(enum.StrEnum):
    """Kinds of task (``docs/service.md``), also the kinds of order the coordinator sends a
    robot (``fleet/<robot>/task``; ``idle`` is an order, never a task)."""

    PATROL = "patrol"
    PICK = "pick"
    GO_TO = "go_to"
    INSPECTION = "inspection"
    CHARGE = "charge"
    PARK = "park"
    IDLE = "idle"


class TreeKind(enum.StrEnum):
    """Which of a config's tasks a fleet starts with (``fleet run --tree``): its routes
    (``patrol``), its picks (``picking``) or both (``tasks``). Every robot runs the one task
    tree (:func:`nodes.task_tree.task_tree`), which takes any task kind at runtime;
    :func:`nodes.build_tree` still builds the single-purpose patrol and picking trees."""

    PATROL = "patrol"
    PICKING = "picking"
    TASKS = "tasks"


class GoalStatus(enum.Enum):
    """Lifecycle of one goal, as in ``action_msgs/GoalStatus``."""

    PENDING = "pending"  # sent, not yet accepted by the server
    EXECUTING = "executing"
    CANCELING = "canceling"
    SUCCEEDED = "succeeded"
    CANCELED = "canceled"
    ABORTED = "aborted"
    REJECTED = "rejected"

    @property
    def terminal(self) -> bool:
        return self in (GoalStatus.SUCCEEDED, GoalStatus.CANCELED, GoalStatus.ABORTED, GoalStatus.REJECTED)


class TaskResult(enum.Enum):
    """What ``nav2_simple_commander.TaskResult`` reports for a finished task."""

    UNKNOWN = 0
    SUCCEEDED = 1
    CANCELED = 2
    FAILED = 3


class ErrorCode(enum.IntEnum):
    """Nav2 Jazzy result error codes used by the simulator and mapped by every backend.

    Navigators (``navigate_to_pose`` / ``navigate_through_poses``) forward the code of the
    planner or controller that failed, as Nav2 Jazzy's bt_navigator does.
    """

    NONE = 0
    # nav2_msgs/action/FollowPath
    CONTROLLER_UNKNOWN = 100
    INVALID_CONTROLLER = 101
    CONTROLLER_TF_ERROR = 102
    INVALID_PATH = 103
    PATIENCE_EXCEEDED = 104
    FAILED_TO_MAKE_PROGRESS = 105
    NO_VALID_CONTROL = 106
    CONTROLLER_TIMED_OUT = 107
    # nav2_msgs/action/ComputePathToPose
    PLANNER_UNKNOWN = 200
    INVALID_PLANNER = 201
    PLANNER_TF_ERROR = 202
    START_OUTSIDE_MAP = 203
    GOAL_OUTSIDE_MAP = 204
    START_OCCUPIED = 205
    GOAL_OCCUPIED = 206
    PLANNER_TIMEOUT = 207
    NO_VALID_PATH = 208
    # nav2_msgs/action/ComputePathThroughPoses (the ComputePathToPose codes + 100)
    THROUGH_POSES_UNKNOWN = 300
    THROUGH_POSES_INVALID_PLANNER = 301
    THROUGH_POSES_TF_ERROR = 302
    THROUGH_POSES_START_OUTSIDE_MAP = 303
    THROUGH_POSES_GOAL_OUTSIDE_MAP = 304
    THROUGH_POSES_START_OCCUPIED = 305
    THROUGH_POSES_GOAL_OCCUPIED = 306
    THROUGH_POSES_TIMEOUT = 307
    THROUGH_POSES_NO_VALID_PATH = 308
    NO_VIAPOINTS_GIVEN = 309
    # nav2_msgs/action/SmoothPath
    SMOOTHER_UNKNOWN = 500
    INVALID_SMOOTHER = 501
    SMOOTHER_TIMEOUT = 502
    SMOOTHED_PATH_IN_COLLISION = 503
    FAILED_TO_SMOOTH_PATH = 504
    SMOOTHER_INVALID_PATH = 505
    # nav2_msgs/action/FollowWaypoints
    WAYPOINT_UNKNOWN = 600
    TASK_EXECUTOR_FAILED = 601
    # nav2_msgs/action/Spin
    SPIN_UNKNOWN = 700
    SPIN_TIMEOUT = 701
    SPIN_COLLISION_AHEAD = 703
    # nav2_msgs/action/BackUp
    BACKUP_UNKNOWN = 710
    BACKUP_TIMEOUT = 711
    BACKUP_INVALID_INPUT = 713
    BACKUP_COLLISION_AHEAD = 714
    # nav2_msgs/action/DriveOnHeading
    DRIVE_UNKNOWN = 720
    DRIVE_TIMEOUT = 721
    DRIVE_COLLISION_AHEAD = 723
    DRIVE_INVALID_INPUT = 724
    # Fleet-level codes (not Nav2's): the safety watchdog stopped the robot (its localization
    # was lost or its navigation server went down), and the goal ended with it.
    SAFETY_STOPPED = 9998
    # Navigator-level (NavigateToPose UNKNOWN in Nav2 Jazzy is reported as 0 + error_msg);
    # used when the server itself vanished or a goal could not be delivered.
    SERVER_UNAVAILABLE = 9999


@dataclass(frozen=True)
class Feedback:
    """Latest feedback of a goal. Fields not produced by an action stay ``None``.

    Navigation actions fill ``current_pose``, ``navigation_time_s``,
    ``estimated_time_remaining_s``, ``distance_remaining_m``, ``number_of_recoveries`` and
    (NavigateThroughPoses) ``number_of_poses_remaining``; FollowWaypoints fills
    ``current_waypoint``; Spin ``angular_distance_traveled``; BackUp / DriveOnHeading
    ``distance_traveled``; Wait ``time_left_s``.
    """

    current_pose: Pose2D | None = None
    navigation_time_s: float | None = None
    estimated_time_remaining_s: float | None = None
    distance_remaining_m: float | None = None
    number_of_recoveries: int | None = None
    number_of_poses_remaining: int | None = None
    current_waypoint: int | None = None
    angular_distance_traveled: float | None = None
    distance_traveled: float | None = None
    time_left_s: float | None = None


@dataclass(frozen=True)
class GoalState:
    """A snapshot of one goal: its status, latest feedback and (when terminal) result.

    ``missed_waypoints`` is only used by FollowWaypoints (indices into the goal's poses);
    ``path`` by the goals that compute one (ComputePathToPose, ComputePathThroughPoses,
    SmoothPath: the path of a SUCCEEDED goal, ``()`` otherwise).
    """

    goal_id: str
    kind: str
    status: GoalStatus
    feedback: Feedback = Feedback()
    error_code: int = 0
    error_msg: str = ""
    missed_waypoints: tuple[int, ...] = ()
    path: Path = ()

    @property
    def result(self) -> TaskResult:
        if self.status is GoalStatus.SUCCEEDED:
            return TaskResult.SUCCEEDED
        if self.status is GoalStatus.CANCELED:
            return TaskResult.CANCELED
        if self.status in (GoalStatus.ABORTED, GoalStatus.REJECTED):
            return TaskResult.FAILED
        return TaskResult.UNKNOWN


@dataclass(frozen=True)
class RobotState:
    """What a backend knows about its robot right now.

    ``pose`` is ``None`` until the robot is localized (the map pose estimate). ``battery`` is a
    fraction in [0, 1]. ``stuck`` is true when the robot has made no progress for the
    backend's stuck time while it was trying to move. ``charging`` is true while the robot
    stands on a charger.

    Health (what :mod:`fleet.health` turns into diagnostics and the safety watchdog reads):
    ``localized`` is false while the localizer has no converged estimate (lost, or an initial
    pose it could not match); ``pose_age_s`` is how old the pose estimate is (seconds of the
    backend's clock since the localizer last confirmed it); ``battery_known`` is false when
    no battery sensor reports (``battery`` is then an assumption); ``navigation_ready`` is
    false while the robot's navigation server is down, unreachable or not active;
    ``safety_stop`` names why the robot's own watchdog stopped it (``""``: not stopped).
    """

    pose: Pose2D | None
    linear_velocity: float = 0.0
    angular_velocity: float = 0.0
    battery: float = 1.0
    charging: bool = False
    stuck: bool = False
    distance_m: float = 0.0
    collisions: int = 0
    localized: bool = True
    pose_age_s: float = 0.0
    battery_known: bool = True
    navigation_ready: bool = True
    safety_stop: str = ""


_T = TypeVar("_T")


def frozen_factory(cls: type[_T]) -> Callable[..., _T]:
    """A keyword-only constructor of the dataclass ``cls`` that builds the very instance
    ``cls(**fields)`` would (same class, same attribute dict in field order) without the
    generated ``__init__``, whose one ``object.__setattr__`` per field of a frozen dataclass
    is most of the cost of the goal and robot snapshots polled every tick (about 1 µs each).
    Every field without a default must be passed. For anything but a plain dataclass (slots,
    ``__post_init__``, default factories, fields outside ``__init__``) it returns ``cls``."""
    fields = dataclasses.fields(cls) if dataclasses.is_dataclass(cls) else ()
    plain = (
        bool(fields)
        and "__slots__" not in vars(cls)
        and not hasattr(cls, "__post_init__")
        and all(f.init and f.default_factory is dataclasses.MISSING for f in fields)
    )
    if not plain:
        return cls
    template = {f.name: None if f.default is dataclasses.MISSING else f.default for f in fields}
    new = object.__new__

    def make(**values: object) -> _T:
        obj = new(cls)
        state = obj.__dict__
        state.update(template)
        state.update(values)
        return obj

    return make
