"""Conversions between the fleet's value types and ROS 2 / nav2_msgs messages.

Frames: poses are in ``map``; yaw is the rotation about +z. Durations are seconds as float
on the fleet side and ``builtin_interfaces/Duration`` on the ROS side. The action of a goal
is named by the goal's ``kind`` (Nav2's action server name, e.g. ``navigate_to_pose``).
"""

from __future__ import annotations

import math
from typing import TypeAlias

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from nav2_msgs.action import (
    BackUp as BackUpAction,
)
from nav2_msgs.action import (
    ComputePathThroughPoses,
    ComputePathToPose,
    FollowPath,
    SmoothPath,
)
from nav2_msgs.action import (
    DriveOnHeading as DriveOnHeadingAction,
)
from nav2_msgs.action import (
    FollowWaypoints as FollowWaypointsAction,
)
from nav2_msgs.action import (
    NavigateThroughPoses as NavigateThroughPosesAction,
)
from nav2_msgs.action import (
    NavigateToPose as NavigateToPoseAction,
)
from nav2_msgs.action import (
    Spin as SpinAction,
)
from nav2_msgs.action import (
    Wait as WaitAction,
)
from nav2_msgs.msg import MissedWaypoint
from nav_msgs.msg import Path as PathMsg
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fleet.types import (
    BackUp,
    DriveOnHeading,
    Feedback,
    FollowWaypoints,
    Goal,
    GoalState,
    NavigateThroughPoses,
    NavigateToPose,
    Path,
    Pose2D,
    Spin,
    Wait,
)
from fleet.types import (
    ComputePathThroughPoses as ComputePathThroughPosesGoal,
)
from fleet.types import (
    ComputePathToPose as ComputePathToPoseGoal,
)
from fleet.types import (
    FollowPath as FollowPathGoal,
)
from fleet.types import (
    SmoothPath as SmoothPathGoal,
)

#: A Nav2 action type, and the Goal / Feedback / Result messages of one. nav2_msgs carries no
#: type information (mypy sees these as ``Any``); the aliases name what a function takes.
ActionType: TypeAlias = (
    NavigateThroughPosesAction
    | NavigateToPoseAction
    | FollowWaypointsAction
    | SpinAction
    | BackUpAction
    | DriveOnHeadingAction
    | WaitAction
    | FollowPath
    | ComputePathToPose
    | ComputePathThroughPoses
    | SmoothPath
)
GoalMsg: TypeAlias = (
    NavigateThroughPosesAction.Goal
    | NavigateToPoseAction.Goal
    | FollowWaypointsAction.Goal
    | SpinAction.Goal
    | BackUpAction.Goal
    | DriveOnHeadingAction.Goal
    | WaitAction.Goal
    | FollowPath.Goal
    | ComputePathToPose.Goal
    | ComputePathThroughPoses.Goal
    | SmoothPath.Goal
)
FeedbackMsg: TypeAlias = (
    NavigateThroughPosesAction.Feedback
    | NavigateToPoseAction.Feedback
    | FollowWaypointsAction.Feedback
    | SpinAction.Feedback
    | BackUpAction.Feedback
    | DriveOnHeadingAction.Feedback
    | WaitAction.Feedback
    | FollowPath.Feedback
)
ResultMsg: TypeAlias = (
    NavigateThroughPosesAction.Result
    | NavigateToPoseAction.Result
    | FollowWaypointsAction.Result
    | SpinAction.Result
    | BackUpAction.Result
    | DriveOnHeadingAction.Result
    | WaitAction.Result
    | FollowPath.Result
    | ComputePathToPose.Result
    | ComputePathThroughPoses.Result
    | SmoothPath.Result
)

#: The navigation actions a robot serves and the fleet's backend drives (Nav2's server names).
NAVIGATION_ACTIONS = (
    "navigate_through_poses",
    "navigate_to_pose",
    "follow_waypoints",
    "spin",
    "backup",
    "drive_on_heading",
    "wait",
)
#: QoS of ``amcl_pose`` as Nav2's AMCL publishes it (and BasicNavigator subscribes).
AMCL_POSE_QOS = QoSProfile(
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
)

#: The controller, planner and smoother actions (Nav2's controller_server, planner_server and
#: smoother_server serve them beside the navigators).
PLANNING_ACTIONS = ("follow_path", "compute_path_to_pose", "compute_path_through_poses", "smooth_path")
#: Nav2's services that clear a whole costmap, by the costmap they clear.
CLEAR_COSTMAP_SERVICES = {
    "global": "global_costmap/clear_entirely_global_costmap",
    "local": "local_costmap/clear_entirely_local_costmap",
}

#: Nav2 action type of each goal kind (the kind is also the action server's name): the
#: :data:`NAVIGATION_ACTIONS` first, then the controller, planner and smoother actions.
ACTION_TYPES: dict[str, type[ActionType]] = {
    "navigate_through_poses": NavigateThroughPosesAction,
    "navigate_to_pose": NavigateToPoseAction,
    "follow_waypoints": FollowWaypointsAction,
    "spin": SpinAction,
    "backup": BackUpAction,
    "drive_on_heading": DriveOnHeadingAction,
    "wait": WaitAction,
    "follow_path": FollowPath,
    "compute_path_to_pose": ComputePathToPose,
    "compute_path_through_poses": ComputePathThroughPoses,
    "smooth_path": SmoothPath,
}


# -- scalars ------------------------------------------------------------------------------


def yaw_to_quaternion(yaw: float) -> Quaternion:
    """Quaternion of a rotation by ``yaw`` radians about +z."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))


def quaternion_to_yaw(q: Quaternion) -> float:
    """Yaw (radians, in [-pi, pi]) of a quaternion; roll and pitch are ignored."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def seconds_to_duration(s: float) -> Duration:
    """``builtin_interfaces/Duration`` of ``s`` seconds (negative values clamp to 0)."""
    s = max(0.0, float(s)) if math.isfinite(s) else 0.0
    sec = int(s)
    return Duration(sec=sec, nanosec=min(999_999_999, int(round((s - sec) * 1e9))))


def duration_to_seconds(d: Duration) -> float:
    return float(d.sec) + float(d.nanosec) * 1e-9


def seconds_to_time(s: float) -> Time:
    """``builtin_interfaces/Time`` of ``s`` seconds (a simulated or wall timestamp)."""
    s = max(0.0, float(s))
    sec = int(s)
    return Time(sec=sec, nanosec=min(999_999_999, int(round((s - sec) * 1e9))))


# -- poses --------------------------------------------------------------------------------


def pose2d_to_pose(p: Pose2D) -> Pose:
    return Pose(position=Point(x=float(p.x), y=float(p.y), z=0.0), orientation=yaw_to_quaternion(p.theta))


def pose_to_pose2d(p: Pose) -> Pose2D:
    return Pose2D(float(p.position.x), float(p.position.y), quaternion_to_yaw(p.orientation))


def pose2d_to_pose_stamped(p: Pose2D, stamp: Time | None = None, frame_id: str = "map") -> PoseStamped:
    """A ``PoseStamped`` in ``frame_id`` (default ``map``) for a fleet pose."""
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.pose = pose2d_to_pose(p)
    return msg


def pose_stamped_to_pose2d(msg: PoseStamped) -> Pose2D:
    """The fleet pose of a ``PoseStamped`` (its frame is assumed to be ``map``)."""
    return pose_to_pose2d(msg.pose)


# -- goals --------------------------------------------------------------------------------


def goal_to_msg(goal: Goal) -> GoalMsg:
    """The Nav2 ``<Action>.Goal`` message of a fleet goal (send it to the action ``goal.kind``)."""
    if isinstance(goal, NavigateThroughPoses):
        g = NavigateThroughPosesAction.Goal()
        g.poses = [pose2d_to_pose_stamped(p) for p in goal.poses]
        g.behavior_tree = goal.behavior_tree
        return g
    if isinstance(goal, NavigateToPose):
        g = NavigateToPoseAction.Goal()
        g.pose = pose2d_to_pose_stamped(goal.pose)
        g.behavior_tree = goal.behavior_tree
        return g
    if isinstance(goal, FollowWaypoints):
        g = FollowWaypointsAction.Goal()
        g.poses = [pose2d_to_pose_stamped(p) for p in goal.poses]
        return g
    if isinstance(goal, Spin):
        g = SpinAction.Goal()
        g.target_yaw = float(goal.target_yaw)
        g.time_allowance = seconds_to_duration(goal.time_allowance_s)
        return g
    if isinstance(goal, (BackUp, DriveOnHeading)):  # the same goal fields, two actions
        g = (BackUpAction if isinstance(goal, BackUp) else DriveOnHeadingAction).Goal()
        g.target = Point(x=float(goal.distance_m), y=0.0, z=0.0)
        g.speed = float(goal.speed_mps)
        g.time_allowance = seconds_to_duration(goal.time_allowance_s)
        return g
    if isinstance(goal, Wait):
        g = WaitAction.Goal()
        g.time = seconds_to_duration(goal.duration_s)
        return g
    return planning_goal_to_msg(goal)


def planning_goal_to_msg(goal: Goal) -> GoalMsg:
    """The Nav2 goal message of a FollowPath, ComputePathToPose, ComputePathThroughPoses or
    SmoothPath goal (TypeError for another goal: ClearCostmaps is a service call)."""
    if isinstance(goal, FollowPathGoal):
        g = FollowPath.Goal()
        g.path = path_to_msg(goal.path)
        g.controller_id = goal.controller_id
        g.goal_checker_id = goal.goal_checker_id
        return g
    if isinstance(goal, (ComputePathToPoseGoal, ComputePathThroughPosesGoal)):
        if isinstance(goal, ComputePathToPoseGoal):
            g = ComputePathToPose.Goal()
            g.goal = pose2d_to_pose_stamped(goal.goal)
        else:
            g = ComputePathThroughPoses.Goal()
            g.goals = [pose2d_to_pose_stamped(p) for p in goal.goals]
        g.use_start = goal.start is not None
        if goal.start is not None:
            g.start = pose2d_to_pose_stamped(goal.start)
        g.planner_id = goal.planner_id
        return g
    if isinstance(goal, SmoothPathGoal):
        g = SmoothPath.Goal()
        g.path = path_to_msg(goal.path)
        g.smoother_id = goal.smoother_id
        g.max_smoothing_duration = seconds_to_duration(goal.max_smoothing_duration_s)
        g.check_for_collisions = bool(goal.check_for_collisions)
        return g
    raise TypeError(f"no Nav2 action for goal type {type(goal).__name__}")


def msg_to_goal(kind: str, msg: GoalMsg) -> Goal:
    """The fleet goal of a Nav2 goal message received on action ``kind``.

    BackUp takes the magnitude of ``target.x`` and ``speed`` (as Nav2's behavior server does);
    DriveOnHeading takes the magnitudes too (the caller checks that the signs agree).
    """
    if kind == "navigate_through_poses":
        return NavigateThroughPoses(tuple(pose_stamped_to_pose2d(p) for p in msg.poses), msg.behavior_tree)
    if kind == "navigate_to_pose":
        return NavigateToPose(pose_stamped_to_pose2d(msg.pose), msg.behavior_tree)
    if kind == "follow_waypoints":
        return FollowWaypoints(tuple(pose_stamped_to_pose2d(p) for p in msg.poses))
    if kind == "spin":
        return Spin(float(msg.target_yaw), duration_to_seconds(msg.time_allowance))
    if kind == "backup":
        return BackUp(
            abs(float(msg.target.x)), abs(float(msg.speed)), duration_to_seconds(msg.time_allowance)
        )
    if kind == "drive_on_heading":
        return DriveOnHeading(
            abs(float(msg.target.x)), abs(float(msg.speed)), duration_to_seconds(msg.time_allowance)
        )
    if kind == "wait":
        return Wait(duration_to_seconds(msg.time))
    if kind == "follow_path":
        return FollowPathGoal(msg_to_path(msg.path), msg.controller_id, msg.goal_checker_id)
    if kind == "compute_path_to_pose":
        start = pose_stamped_to_pose2d(msg.start) if msg.use_start else None
        return ComputePathToPoseGoal(pose_stamped_to_pose2d(msg.goal), start, msg.planner_id)
    if kind == "compute_path_through_poses":
        start = pose_stamped_to_pose2d(msg.start) if msg.use_start else None
        goals = tuple(pose_stamped_to_pose2d(p) for p in msg.goals)
        return ComputePathThroughPosesGoal(goals, start, msg.planner_id)
    if kind == "smooth_path":
        return SmoothPathGoal(
            msg_to_path(msg.path),
            msg.smoother_id,
            duration_to_seconds(msg.max_smoothing_duration),
            bool(msg.check_for_collisions),
        )
    raise ValueError(f"no fleet goal for action {kind!r}")


def path_to_msg(path: Path, stamp: Time | None = None) -> PathMsg:
    """A ``nav_msgs/Path`` in ``map`` of a fleet path."""
    m = PathMsg()
    m.header.frame_id = "map"
    if stamp is not None:
        m.header.stamp = stamp
    m.poses = [pose2d_to_pose_stamped(p, stamp) for p in path]
    return m


def msg_to_path(m: PathMsg) -> Path:
    """The fleet path of a ``nav_msgs/Path`` (its frame is assumed to be ``map``)."""
    return tuple(pose_stamped_to_pose2d(p) for p in m.poses)


# -- feedback -----------------------------------------------------------------------------


def feedback_to_msg(kind: str, fb: Feedback, stamp: Time | None = None) -> FeedbackMsg:
    """The Nav2 ``<Action>.Feedback`` for the fleet feedback of a goal on action ``kind``."""
    action = ACTION_TYPES[kind]
    m = action.Feedback()
    if kind in ("navigate_through_poses", "navigate_to_pose"):
        if fb.current_pose is not None:
            m.current_pose = pose2d_to_pose_stamped(fb.current_pose, stamp)
        m.navigation_time = seconds_to_duration(fb.navigation_time_s or 0.0)
        m.estimated_time_remaining = seconds_to_duration(fb.estimated_time_remaining_s or 0.0)
        m.number_of_recoveries = int(fb.number_of_recoveries or 0)
        m.distance_remaining = float(fb.distance_remaining_m or 0.0)
        if kind == "navigate_through_poses":
            m.number_of_poses_remaining = int(fb.number_of_poses_remaining or 0)
    elif kind == "follow_waypoints":
        m.current_waypoint = int(fb.current_waypoint or 0)
    elif kind == "spin":
        m.angular_distance_traveled = float(fb.angular_distance_traveled or 0.0)
    elif kind in ("backup", "drive_on_heading"):
        m.distance_traveled = float(fb.distance_traveled or 0.0)
    elif kind == "wait":
        m.time_left = seconds_to_duration(fb.time_left_s or 0.0)
    elif kind == "follow_path":
        m.distance_to_goal = float(fb.distance_remaining_m or 0.0)
    return m


def follow_path_feedback(distance_to_goal_m: float, speed_mps: float) -> FollowPath.Feedback:
    """FollowPath's feedback: distance to the path's end (m) and the robot's speed (m/s)."""
    m = FollowPath.Feedback()
    m.distance_to_goal = float(distance_to_goal_m)
    m.speed = float(speed_mps)
    return m


def msg_to_feedback(kind: str, m: FeedbackMsg) -> Feedback:
    """The fleet :class:`~fleet.types.Feedback` of a Nav2 feedback message on action ``kind``."""
    if kind in ("navigate_through_poses", "navigate_to_pose"):
        return Feedback(
            current_pose=pose_stamped_to_pose2d(m.current_pose),
            navigation_time_s=duration_to_seconds(m.navigation_time),
            estimated_time_remaining_s=duration_to_seconds(m.estimated_time_remaining),
            distance_remaining_m=float(m.distance_remaining),
            number_of_recoveries=int(m.number_of_recoveries),
            number_of_poses_remaining=(
                int(m.number_of_poses_remaining) if kind == "navigate_through_poses" else None
            ),
        )
    if kind == "follow_waypoints":
        return Feedback(current_waypoint=int(m.current_waypoint))
    if kind == "spin":
        return Feedback(angular_distance_traveled=float(m.angular_distance_traveled))
    if kind in ("backup", "drive_on_heading"):
        return Feedback(distance_traveled=float(m.distance_traveled))
    if kind == "wait":
        return Feedback(time_left_s=duration_to_seconds(m.time_left))
    if kind == "follow_path":
        return Feedback(distance_remaining_m=float(m.distance_to_goal))
    return Feedback()


# -- results ------------------------------------------------------------------------------


def result_to_msg(
    kind: str, state: GoalState, poses: tuple[Pose2D, ...] = (), elapsed_s: float = 0.0
) -> ResultMsg:
    """The Nav2 ``<Action>.Result`` of a finished goal: ``error_code`` / ``error_msg`` from the
    state; FollowWaypoints lists its missed waypoints (``poses`` are the goal's poses);
    behaviors report ``total_elapsed_time``."""
    m = ACTION_TYPES[kind].Result()
    m.error_code = int(state.error_code)
    m.error_msg = state.error_msg
    if kind == "follow_waypoints":
        missed = []
        for i in state.missed_waypoints:
            mw = MissedWaypoint()
            mw.index = int(i)
            if 0 <= i < len(poses):
                mw.goal = pose2d_to_pose_stamped(poses[i])
            mw.error_code = int(state.error_code) if state.error_code else 0
            missed.append(mw)
        m.missed_waypoints = missed
    if kind in ("spin", "backup", "drive_on_heading", "wait"):
        m.total_elapsed_time = seconds_to_duration(elapsed_s)
    if kind in ("compute_path_to_pose", "compute_path_through_poses"):
        m.path = path_to_msg(state.path)
        m.planning_time = seconds_to_duration(elapsed_s)
    if kind == "smooth_path":
        m.path = path_to_msg(state.path)
        m.smoothing_duration = seconds_to_duration(elapsed_s)
        m.was_completed = bool(state.path)
    return m


def result_path(kind: str, result: ResultMsg) -> Path:
    """The path a planner or smoother result carries (``()`` for other actions)."""
    if kind in ("compute_path_to_pose", "compute_path_through_poses", "smooth_path"):
        return msg_to_path(result.path)
    return ()
