"""The navigation protocol between ``fleet sim`` and :class:`~fleet.bus.nav_client.ZenohNavBackend`:
goal and cancel requests, state messages (robot state and goal states), the simulator clock,
and the codec of the shared value types of :mod:`fleet.types` (goals, feedback, goal states,
robot states). Poses travel as ``[x, y, theta]`` (``map`` frame, meters, radians); numbers
must be finite. Schemas and examples: ``docs/status_bus.md``."""

from __future__ import annotations

import math
from typing import Final, Union

import msgspec
from msgspec import UNSET, Raw, Struct, UnsetType

from fleet.messages.codec import (
    MAX_BRIDGE_PAYLOAD,
    Codec,
    Count,
    Finite,
    LongText,
    Pose,
    Poses,
    RobotName,
    Text,
    check_finite,
    encode,
    explain,
    to_builtins,
)
from fleet.messages.records import pose_tuple
from fleet.types import (
    BackUp,
    ClearCostmaps,
    ComputePathThroughPoses,
    ComputePathToPose,
    Costmap,
    DriveOnHeading,
    Feedback,
    FollowPath,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    RobotState,
    SmoothPath,
    Spin,
    Wait,
)

#: Version of the navigation protocol's messages (field ``v``).
BRIDGE_VERSION: Final = 1

BehaviorTree = LongText


# -- goals: one struct per Nav2 action, tagged by ``kind`` ---------------------------------


class NavigateToPoseMsg(Struct, frozen=True, tag_field="kind", tag="navigate_to_pose"):
    pose: Pose
    behavior_tree: BehaviorTree = ""


class NavigateThroughPosesMsg(Struct, frozen=True, tag_field="kind", tag="navigate_through_poses"):
    poses: Poses
    behavior_tree: BehaviorTree = ""


class FollowWaypointsMsg(Struct, frozen=True, tag_field="kind", tag="follow_waypoints"):
    poses: Poses


class SpinMsg(Struct, frozen=True, tag_field="kind", tag="spin"):
    target_yaw: Finite
    time_allowance_s: Finite


class BackUpMsg(Struct, frozen=True, tag_field="kind", tag="backup"):
    distance_m: Finite
    speed_mps: Finite
    time_allowance_s: Finite


class DriveOnHeadingMsg(BackUpMsg, frozen=True, tag="drive_on_heading"):
    pass


class WaitMsg(Struct, frozen=True, tag_field="kind", tag="wait"):
    duration_s: Finite


class FollowPathMsg(Struct, frozen=True, tag_field="kind", tag="follow_path"):
    path: Poses
    controller_id: Text = ""
    goal_checker_id: Text = ""


class ComputePathToPoseMsg(Struct, frozen=True, tag_field="kind", tag="compute_path_to_pose"):
    goal: Pose
    start: Pose | None = None
    planner_id: Text = ""


class ComputePathThroughPosesMsg(Struct, frozen=True, tag_field="kind", tag="compute_path_through_poses"):
    goals: Poses
    start: Pose | None = None
    planner_id: Text = ""


class SmoothPathMsg(Struct, frozen=True, tag_field="kind", tag="smooth_path"):
    path: Poses
    smoother_id: Text = ""
    max_smoothing_duration_s: Finite = 3.0
    check_for_collisions: bool = False


class ClearCostmapsMsg(Struct, frozen=True, tag_field="kind", tag="clear_costmaps"):
    costmap: Costmap = Costmap.BOTH


GoalMsg = Union[  # noqa: UP007 - a runtime union msgspec decodes by its ``kind`` tag
    NavigateToPoseMsg,
    NavigateThroughPosesMsg,
    FollowWaypointsMsg,
    SpinMsg,
    BackUpMsg,
    DriveOnHeadingMsg,
    WaitMsg,
    FollowPathMsg,
    ComputePathToPoseMsg,
    ComputePathThroughPosesMsg,
    SmoothPathMsg,
    ClearCostmapsMsg,
]

#: The goal kinds (Nav2 action names) the protocol carries.
GOAL_KINDS: Final = (
    "navigate_to_pose",
    "navigate_through_poses",
    "follow_waypoints",
    "spin",
    "backup",
    "drive_on_heading",
    "wait",
    "follow_path",
    "compute_path_to_pose",
    "compute_path_through_poses",
    "smooth_path",
    "clear_costmaps",
)


def _poses(poses: tuple[Pose2D, ...]) -> tuple[tuple[float, float, float], ...]:
    return tuple(pose_tuple(p) for p in poses)


def _pose_or_none(p: Pose2D | None) -> tuple[float, float, float] | None:
    return None if p is None else pose_tuple(p)


def goal_message(goal: Goal) -> GoalMsg:
    """The wire form of a goal of :mod:`fleet.types`; TypeError for anything else."""
    if isinstance(goal, NavigateToPose):
        return NavigateToPoseMsg(pose_tuple(goal.pose), goal.behavior_tree)
    if isinstance(goal, NavigateThroughPoses):
        return NavigateThroughPosesMsg(tuple(pose_tuple(p) for p in goal.poses), goal.behavior_tree)
    if isinstance(goal, FollowWaypoints):
        return FollowWaypointsMsg(tuple(pose_tuple(p) for p in goal.poses))
    if isinstance(goal, Spin):
        return SpinMsg(goal.target_yaw, goal.time_allowance_s)
    if isinstance(goal, BackUp):
        return BackUpMsg(goal.distance_m, goal.speed_mps, goal.time_allowance_s)
    if isinstance(goal, DriveOnHeading):
        return DriveOnHeadingMsg(goal.distance_m, goal.speed_mps, goal.time_allowance_s)
    if isinstance(goal, Wait):
        return WaitMsg(goal.duration_s)
    if isinstance(goal, FollowPath):
        return FollowPathMsg(_poses(goal.path), goal.controller_id, goal.goal_checker_id)
    if isinstance(goal, ComputePathToPose):
        return ComputePathToPoseMsg(pose_tuple(goal.goal), _pose_or_none(goal.start), goal.planner_id)
    if isinstance(goal, ComputePathThroughPoses):
        return ComputePathThroughPosesMsg(_poses(goal.goals), _pose_or_none(goal.start), goal.planner_id)
    if isinstance(goal, SmoothPath):
        return SmoothPathMsg(
            _poses(goal.path), goal.smoother_id, goal.max_smoothing_duration_s, goal.check_for_collisions
        )
    if isinstance(goal, ClearCostmaps):
        return ClearCostmapsMsg(Costmap(goal.costmap))
    raise TypeError(f"not a navigation goal: {type(goal).__name__}")


def goal_of(msg: GoalMsg) -> Goal:
    """The goal of :mod:`fleet.types` a wire goal stands for."""
    if isinstance(msg, NavigateToPoseMsg):
        return NavigateToPose(Pose2D(*msg.pose), behavior_tree=msg.behavior_tree)
    if isinstance(msg, NavigateThroughPosesMsg):
        return NavigateThroughPoses(tuple(Pose2D(*p) for p in msg.poses), behavior_tree=msg.behavior_tree)
    if isinstance(msg, FollowWaypointsMsg):
        return FollowWaypoints(tuple(Pose2D(*p) for p in msg.poses))
    if isinstance(msg, SpinMsg):
        return Spin(msg.target_yaw, time_allowance_s=msg.time_allowance_s)
    if isinstance(msg, DriveOnHeadingMsg):
        return DriveOnHeading(msg.distance_m, speed_mps=msg.speed_mps, time_allowance_s=msg.time_allowance_s)
    if isinstance(msg, BackUpMsg):
        return BackUp(msg.distance_m, speed_mps=msg.speed_mps, time_allowance_s=msg.time_allowance_s)
    if isinstance(msg, FollowPathMsg):
        return FollowPath(_pose2ds(msg.path), msg.controller_id, msg.goal_checker_id)
    if isinstance(msg, ComputePathToPoseMsg):
        start = None if msg.start is None else Pose2D(*msg.start)
        return ComputePathToPose(Pose2D(*msg.goal), start, msg.planner_id)
    if isinstance(msg, ComputePathThroughPosesMsg):
        start = None if msg.start is None else Pose2D(*msg.start)
        return ComputePathThroughPoses(_pose2ds(msg.goals), start, msg.planner_id)
    if isinstance(msg, SmoothPathMsg):
        return SmoothPath(
            _pose2ds(msg.path), msg.smoother_id, msg.max_smoothing_duration_s, msg.check_for_collisions
        )
    if isinstance(msg, ClearCostmapsMsg):
        return ClearCostmaps(msg.costmap)
    return Wait(msg.duration_s)


def _pose2ds(poses: tuple[tuple[float, float, float], ...]) -> tuple[Pose2D, ...]:
    return tuple(Pose2D(*p) for p in poses)


def goal_to_dict(goal: Goal) -> dict[str, object]:
    """``{"kind": <Nav2 action name>, ...fields}``; poses as ``[x, y, theta]``. ValueError for
    a non-finite number (JSON cannot carry it), TypeError for an object that is not a goal."""
    msg = goal_message(goal)
    check_finite(msg, "goal")
    return to_builtins(msg)


def goal_from_dict(d: object, path: str = "goal") -> Goal:
    """The goal encoded by :func:`goal_to_dict`; ValueError naming the bad field."""
    try:
        msg = msgspec.convert(d, GoalMsg)
    except msgspec.ValidationError as e:
        raise ValueError(explain(e, path, lambda: d, {"kind": GOAL_KINDS})) from None
    return goal_of(msg)


# -- feedback, goal states, robot states ---------------------------------------------------


class FeedbackMsg(Struct, frozen=True, omit_defaults=True):
    """:class:`fleet.types.Feedback` on the wire: only the fields that are set."""

    current_pose: Pose | None = None
    navigation_time_s: Finite | None = None
    estimated_time_remaining_s: Finite | None = None
    distance_remaining_m: Finite | None = None
    angular_distance_traveled: Finite | None = None
    distance_traveled: Finite | None = None
    time_left_s: Finite | None = None
    number_of_recoveries: int | None = None
    number_of_poses_remaining: int | None = None
    current_waypoint: int | None = None


def _finite(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _int(v: int | None) -> int | None:
    return None if v is None else int(v)


def feedback_message(fb: Feedback) -> FeedbackMsg:
    """Only the fields that are set; a non-finite number (or pose) is left out."""
    p = fb.current_pose
    return FeedbackMsg(
        current_pose=None if p is None or not math.isfinite(p.x + p.y + p.theta) else pose_tuple(p),
        navigation_time_s=_finite(fb.navigation_time_s),
        estimated_time_remaining_s=_finite(fb.estimated_time_remaining_s),
        distance_remaining_m=_finite(fb.distance_remaining_m),
        angular_distance_traveled=_finite(fb.angular_distance_traveled),
        distance_traveled=_finite(fb.distance_traveled),
        time_left_s=_finite(fb.time_left_s),
        number_of_recoveries=_int(fb.number_of_recoveries),
        number_of_poses_remaining=_int(fb.number_of_poses_remaining),
        current_waypoint=_int(fb.current_waypoint),
    )


def feedback_of(m: FeedbackMsg) -> Feedback:
    return Feedback(
        current_pose=None if m.current_pose is None else Pose2D(*m.current_pose),
        navigation_time_s=m.navigation_time_s,
        estimated_time_remaining_s=m.estimated_time_remaining_s,
        distance_remaining_m=m.distance_remaining_m,
        number_of_recoveries=m.number_of_recoveries,
        number_of_poses_remaining=m.number_of_poses_remaining,
        current_waypoint=m.current_waypoint,
        angular_distance_traveled=m.angular_distance_traveled,
        distance_traveled=m.distance_traveled,
        time_left_s=m.time_left_s,
    )


class GoalStateMsg(Struct, frozen=True):
    """:class:`fleet.types.GoalState` on the wire, without ``goal_id`` (a state message keys
    goal states by the client's goal id); ``missed_waypoints`` and ``path`` only when
    non-empty."""

    kind: Text
    status: GoalStatus
    feedback: FeedbackMsg = msgspec.field(default_factory=FeedbackMsg)
    error_code: Count = 0
    error_msg: LongText = ""
    missed_waypoints: tuple[Count, ...] | UnsetType = UNSET
    path: Poses | UnsetType = UNSET


def goal_state_message(state: GoalState) -> GoalStateMsg:
    return GoalStateMsg(
        kind=state.kind,
        status=state.status,
        feedback=feedback_message(state.feedback),
        error_code=int(state.error_code),
        error_msg=state.error_msg,
        missed_waypoints=tuple(int(i) for i in state.missed_waypoints) if state.missed_waypoints else UNSET,
        path=_poses(state.path) if state.path else UNSET,
    )


def goal_state_of(goal_id: str, m: GoalStateMsg) -> GoalState:
    return GoalState(
        goal_id=goal_id,
        kind=m.kind,
        status=m.status,
        feedback=feedback_of(m.feedback),
        error_code=m.error_code,
        error_msg=m.error_msg,
        missed_waypoints=() if isinstance(m.missed_waypoints, UnsetType) else m.missed_waypoints,
        path=() if isinstance(m.path, UnsetType) else _pose2ds(m.path),
    )


class RobotStateMsg(Struct, frozen=True):
    """:class:`fleet.types.RobotState` on the wire (every field required)."""

    pose: Pose | None
    linear_velocity: Finite
    angular_velocity: Finite
    battery: Finite
    charging: bool
    stuck: bool
    distance_m: Finite
    collisions: Count


def robot_state_message(st: RobotState) -> RobotStateMsg:
    return RobotStateMsg(
        pose=None if st.pose is None else pose_tuple(st.pose),
        linear_velocity=float(st.linear_velocity),
        angular_velocity=float(st.angular_velocity),
        battery=float(st.battery),
        charging=bool(st.charging),
        stuck=bool(st.stuck),
        distance_m=float(st.distance_m),
        collisions=int(st.collisions),
    )


def robot_state_of(m: RobotStateMsg) -> RobotState:
    return RobotState(
        pose=None if m.pose is None else Pose2D(*m.pose),
        linear_velocity=m.linear_velocity,
        angular_velocity=m.angular_velocity,
        battery=m.battery,
        charging=m.charging,
        stuck=m.stuck,
        distance_m=m.distance_m,
        collisions=m.collisions,
    )


# -- the protocol's messages -----------------------------------------------------------------


class GoalRequest(Struct, frozen=True, tag_field="v", tag=1):
    """``fleet/<robot>/nav/goal``: the client's ``goal_id`` (``<namespace>@<client>#<seq>``),
    its tag ``client`` and per-client ``seq`` (newer goals have larger ones), the goal."""

    goal_id: Text
    client: Text
    seq: Count
    goal: GoalMsg

    def to_json(self) -> bytes:
        """UTF-8 JSON; ValueError naming the field for a NaN or infinite number."""
        return encode(self, "goal_request")


class CancelRequest(Struct, frozen=True, tag_field="v", tag=1):
    """``fleet/<robot>/nav/cancel``: cancel the goal ``goal_id``."""

    goal_id: Text

    def to_json(self) -> bytes:
        return encode(self, "cancel_request")


class NavState(Struct, frozen=True, tag_field="v", tag=1):
    """``fleet/<robot>/nav/state``: simulated time ``t`` (s), the robot state, and the goal
    states by goal id, each kept as raw JSON so that a client parses only its own goals
    (:meth:`goal_state`). ``src``: the serving simulator's session id (its lease,
    ``docs/protocol.md``; ``""`` from an older simulator)."""

    robot: RobotName
    t: Finite
    robot_state: RobotStateMsg
    goals: dict[str, Raw]
    src: Text = ""

    @classmethod
    def build(
        cls, robot: str, t: float, state: RobotState, goals: dict[str, GoalState], src: str = ""
    ) -> NavState:
        """The state message of ``robot`` (goal states keyed by the client's goal ids)."""
        raw = {gid: Raw(encode(goal_state_message(st), f"state.goals[{gid!r}]")) for gid, st in goals.items()}
        return cls(robot, float(t), robot_state_message(state), raw, src)

    def to_json(self) -> bytes:
        return encode(self, "state")

    def goal_state(self, goal_id: str) -> GoalState:
        """The state of ``goal_id`` (KeyError if not listed; ValueError naming the field if
        malformed)."""
        m = GOAL_STATE_CODEC.decode(self.goals[goal_id], f"state.goals[{goal_id!r}]")
        return goal_state_of(goal_id, m)


class ClockMsg(Struct, frozen=True, tag_field="v", tag=1):
    """``fleet/sim/clock``: simulated time ``t`` (s), the simulator's ``step`` count and
    ``step_s``, and its ``speed`` (x real time, ``0`` as fast as possible); ``src`` the
    simulator's session id (its lease, ``docs/protocol.md``; ``""`` from an older one)."""

    t: Finite
    step: Count = 0
    step_s: Finite = 0.0
    speed: Finite = 0.0
    src: Text = ""

    def to_json(self) -> bytes:
        return encode(self, "clock")


_KINDS: Final = {"kind": GOAL_KINDS}
GOAL_REQUEST_CODEC: Final = Codec(GoalRequest, "goal_request", limit=MAX_BRIDGE_PAYLOAD, choices=_KINDS)
CANCEL_REQUEST_CODEC: Final = Codec(CancelRequest, "cancel_request", limit=MAX_BRIDGE_PAYLOAD)
NAV_STATE_CODEC: Final = Codec(NavState, "state", limit=MAX_BRIDGE_PAYLOAD)
CLOCK_CODEC: Final = Codec(ClockMsg, "clock", limit=MAX_BRIDGE_PAYLOAD)
GOAL_STATE_CODEC: Final = Codec(
    GoalStateMsg,
    "goal_state",
    versioned=False,
    limit=MAX_BRIDGE_PAYLOAD,
    choices={"status": tuple(s.value for s in GoalStatus)},
)
