"""Nav2's nodes (``nav2_behavior_tree``, Jazzy) with their ports, as :class:`NodeSpec` s of the
registry: control nodes, decorators, action nodes and conditions. See :mod:`nodes.nav2_leaves`,
:mod:`nodes.nav2_conditions` and :mod:`nodes.control` for what each does here."""

from __future__ import annotations

from py_trees.behaviour import Behaviour

from fleet.types import Mode
from nodes.conditions import IsStuck
from nodes.control import (
    BeforeTick,
    DistanceController,
    GoalUpdatedController,
    PathLongerOnApproach,
    PipelineSequence,
    RateController,
    SingleTrigger,
    SpeedController,
)
from nodes.nav2_conditions import (
    CONTROLLER_RECOVERY_CODES,
    PLANNER_RECOVERY_CODES,
    SMOOTHER_RECOVERY_CODES,
    Check,
    battery_low,
    distance_traveled,
    error_codes_present,
    goal_reached,
    goal_updated,
    poses_near,
    time_expired,
)
from nodes.nav2_leaves import (
    MakeGoal,
    OnDone,
    PortedAction,
    PortedLeaf,
    Refresh,
    cancel_running,
    current_pose,
    make_backup,
    make_clear_costmap,
    make_compute_through_poses,
    make_compute_to_pose,
    make_drive_on_heading,
    make_follow_path,
    make_navigate_through_poses,
    make_navigate_to_pose,
    make_smooth_path,
    make_spin,
    make_wait,
    path_done,
    pose_from_path,
    refresh_follow_path,
    remove_passed_goals,
    selector,
    smoothing_done,
    truncate_path,
)
from nodes.ports import Port, PortType, in_port, out_port
from nodes.recovery import RecoveryNode, RoundRobin
from nodes.registry import Category, NodeArgs, NodeSpec, control, decorator, leaf

_F, _I, _B, _S = PortType.FLOAT, PortType.INT, PortType.BOOL, PortType.STRING
_POSE, _POSES, _PATH, _CODES = PortType.POSE, PortType.POSES, PortType.PATH, PortType.INTS

#: Ports every goal node has: Nav2's server lookup (no effect here), this project's mode, the
#: error code output.
GOAL_PORTS: tuple[Port, ...] = (
    in_port("server_name", _S, doc="Nav2's action server name (no effect: one backend per robot)"),
    in_port("server_timeout", _F, doc="ms (no effect)"),
    in_port("mode", PortType.MODE, doc="robot mode written to the blackboard on start"),
    out_port("error_code_id", _I, doc="0, or the failed goal's Nav2 error code"),
)
FRAME_PORTS = (
    in_port("global_frame", _S, doc="no effect (map)"),
    in_port("robot_base_frame", _S, doc="no effect"),
)


def _mode(a: NodeArgs) -> Mode | None:
    v = a.ports.get("mode")
    return v if isinstance(v, Mode) else None


def goal_node(
    name: str,
    make: MakeGoal,
    ports: tuple[Port, ...],
    doc: str,
    *,
    on_done: OnDone | None = None,
    refresh: Refresh | None = None,
    recovery: str | None = None,
    clear_on_halt: tuple[str, ...] = (),
) -> NodeSpec:
    """The spec of a Nav2 action node sending one goal. ``recovery``: the boolean port that
    says whether the node counts as a recovery (``"always"``: it always does)."""

    def build(a: NodeArgs) -> Behaviour:
        counts = recovery == "always" or (recovery is not None and a.ports.get_bool(recovery, True))
        return PortedAction(
            a.name,
            a.ctx.backend,
            a.ports,
            make,
            on_done=on_done,
            refresh=refresh,
            recovery_key=a.ctx.key(a.ctx.params.recoveries_key) if counts else None,
            clear_on_halt=clear_on_halt,
            mode=_mode(a),
        )

    return leaf(name, Category.ACTION, build, (*ports, *GOAL_PORTS), doc)


def _data(name: str, ports: tuple[Port, ...], doc: str, step_of: object) -> NodeSpec:
    """An instant action node; ``step_of(args)`` returns its step function."""

    def build(a: NodeArgs) -> Behaviour:
        return PortedLeaf(a.name, a.ports, step_of(a))  # type: ignore[operator]

    return leaf(name, Category.ACTION, build, ports, doc)


def _check(name: str, ports: tuple[Port, ...], doc: str, make: object) -> NodeSpec:
    """A condition node; ``make(args)`` returns the behaviour."""
    return leaf(name, Category.CONDITION, make, ports, doc)  # type: ignore[arg-type]


_START = (in_port("start", _POSE), in_port("use_start", _B), in_port("planner_id", _S, '""'))
_CODE_CHECK = (in_port("error_code", _I), in_port("error_codes_to_check", _CODES))
_GOALS_IN = (in_port("goal", _POSE, "{goal}"), in_port("goals", _POSES, "{goals}"))

_ACTIONS: tuple[NodeSpec, ...] = (
    goal_node(
        "ComputePathToPose",
        make_compute_to_pose,
        (in_port("goal", _POSE), *_START, out_port("path", _PATH)),
        "plan a path to goal (the planner server); path on success",
        on_done=path_done,
        clear_on_halt=("path",),
    ),
    goal_node(
        "ComputePathThroughPoses",
        make_compute_through_poses,
        (in_port("goals", _POSES), *_START, out_port("path", _PATH)),
        "plan one path through goals",
        on_done=path_done,
        clear_on_halt=("path",),
    ),
    goal_node(
        "FollowPath",
        make_follow_path,
        (
            in_port("path", _PATH),
            in_port("controller_id", _S),
            in_port("goal_checker_id", _S),
            in_port("progress_checker_id", _S),
        ),
        "drive along path (the controller); a changed path is sent again while running",
        refresh=refresh_follow_path,
    ),
    goal_node(
        "SmoothPath",
        make_smooth_path,
        (
            in_port("unsmoothed_path", _PATH),
            in_port("max_smoothing_duration", _F, "3.0"),
            in_port("check_for_collisions", _B, "false"),
            in_port("smoother_id", _S),
            out_port("smoothed_path", _PATH),
            out_port("smoothing_duration", _F),
            out_port("was_completed", _B),
        ),
        "smooth a path (the smoother server)",
        on_done=smoothing_done,
    ),
    goal_node(
        "ClearEntireCostmap",
        make_clear_costmap,
        (in_port("service_name", _S),),
        "clear the costmap the service name names (global_costmap/... or local_costmap/...)",
    ),
    goal_node(
        "NavigateToPose",
        make_navigate_to_pose,
        (in_port("goal", _POSE), in_port("behavior_tree", _S)),
        "navigate to goal",
    ),
    goal_node(
        "NavigateThroughPoses",
        make_navigate_through_poses,
        (in_port("goals", _POSES), in_port("behavior_tree", _S)),
        "navigate through goals",
    ),
    goal_node(
        "Spin",
        make_spin,
        (
            in_port("spin_dist", _F, "1.57"),
            in_port("time_allowance", _F, "10.0"),
            in_port("is_recovery", _B, "true"),
        ),
        "turn in place by spin_dist rad",
        recovery="is_recovery",
    ),
    goal_node(
        "BackUp",
        make_backup,
        (
            in_port("backup_dist", _F, "0.15"),
            in_port("backup_speed", _F, "0.025"),
            in_port("time_allowance", _F, "10.0"),
        ),
        "drive backwards backup_dist m at backup_speed m/s",
        recovery="always",
    ),
    goal_node(
        "DriveOnHeading",
        make_drive_on_heading,
        (
            in_port("dist_to_travel", _F, "0.15"),
            in_port("speed", _F, "0.025"),
            in_port("time_allowance", _F, "10.0"),
        ),
        "drive forwards dist_to_travel m at speed m/s",
    ),
    goal_node(
        "Wait",
        make_wait,
        (in_port("wait_duration", _F, "1.0"),),
        "stand still wait_duration s",
        recovery="always",
    ),
    _data(
        "RemovePassedGoals",
        (
            in_port("input_goals", _POSES),
            out_port("output_goals", _POSES),
            in_port("radius", _F, "0.5"),
            *FRAME_PORTS,
        ),
        "drop the goals already reached",
        lambda a: remove_passed_goals(a.ctx.backend),
    ),
    _data(
        "TruncatePath",
        (in_port("input_path", _PATH), in_port("distance", _F, "1.0"), out_port("output_path", _PATH)),
        "drop the path's poses within distance of its end",
        lambda a: truncate_path,
    ),
    _data(
        "GetPoseFromPath",
        (in_port("path", _PATH), in_port("index", _I, "0"), out_port("pose", _POSE)),
        "the pose at index (-1: the last)",
        lambda a: pose_from_path,
    ),
    _data(
        "GetCurrentPose",
        (out_port("current_pose", _POSE), *FRAME_PORTS),
        "the robot's pose",
        lambda a: current_pose(a.ctx.backend),
    ),
    *(
        _data(
            f"{what}Selector",
            (in_port("topic_name", _S), in_port(f"default_{key}", _S), out_port(f"selected_{key}", _S)),
            f"outputs default_{key} (no selector topic here)",
            lambda a, key=key: selector(f"default_{key}", f"selected_{key}"),
        )
        for what, key in (
            ("Planner", "planner"),
            ("Controller", "controller"),
            ("Smoother", "smoother"),
            ("GoalChecker", "goal_checker"),
            ("ProgressChecker", "progress_checker"),
        )
    ),
    *(
        _data(
            f"Cancel{what}",
            (in_port("server_name", _S), in_port("server_timeout", _F)),
            f"cancel the robot's running {kind} goal",
            lambda a, kind=kind: cancel_running(a.ctx.backend, (kind,)),
        )
        for what, kind in (
            ("Control", "follow_path"),
            ("Spin", "spin"),
            ("BackUp", "backup"),
            ("DriveOnHeading", "drive_on_heading"),
            ("Wait", "wait"),
        )
    ),
)

_CONDITIONS: tuple[NodeSpec, ...] = (
    _check(
        "GoalReached",
        (in_port("goal", _POSE, "{goal}"), *FRAME_PORTS),
        "the robot within goal_reached_tol of goal",
        lambda a: Check(a.name, a.ports, goal_reached(a.ctx.backend, a.ctx.params.goal_reached_tol)),
    ),
    _check(
        "GoalUpdated",
        _GOALS_IN,
        "goal(s) changed since the last tick",
        lambda a: goal_updated(a.name, a.ports, global_=False),
    ),
    _check(
        "GlobalUpdatedGoal",
        _GOALS_IN,
        "goal(s) changed (kept across halts)",
        lambda a: goal_updated(a.name, a.ports, global_=True),
    ),
    _check(
        "IsStuck", (), "the backend reports the robot stuck", lambda a: IsStuck(a.ctx.backend, name=a.name)
    ),
    _check(
        "IsBatteryLow",
        (
            in_port("min_battery", _F, required=True),
            in_port("battery_topic", _S),
            in_port("is_voltage", _B, "false"),
        ),
        "battery fraction <= min_battery",
        lambda a: Check(a.name, a.ports, battery_low(a.ctx.backend)),
    ),
    _check(
        "IsBatteryCharging",
        (in_port("battery_topic", _S),),
        "the robot is charging",
        lambda a: Check(a.name, a.ports, lambda _p: a.ctx.backend.robot_state().charging),
    ),
    _check(
        "TransformAvailable",
        (in_port("child", _S), in_port("parent", _S)),
        "the robot is localized",
        lambda a: Check(a.name, a.ports, lambda _p: a.ctx.backend.robot_state().pose is not None),
    ),
    _check(
        "InitialPoseReceived",
        (in_port("initial_pose_received", _B, "{initial_pose_received}"),),
        "the port is true",
        lambda a: Check(a.name, a.ports, lambda p: p.get_bool("initial_pose_received")),
    ),
    _check(
        "DistanceTraveled",
        (in_port("distance", _F, "1.0"), *FRAME_PORTS),
        "the robot moved distance m since it was last true",
        lambda a: distance_traveled(a.name, a.ports, a.ctx.backend),
    ),
    _check(
        "TimeExpired",
        (in_port("seconds", _F, "1.0"),),
        "seconds passed since it was last true",
        lambda a: time_expired(a.name, a.ports, a.ctx.clock),
    ),
    _check(
        "PathExpiringTimer",
        (in_port("seconds", _F, "1.0"), in_port("path", _PATH)),
        "seconds passed since it was last true or the path changed",
        lambda a: time_expired(a.name, a.ports, a.ctx.clock, path_port="path"),
    ),
    _check(
        "AreErrorCodesPresent",
        _CODE_CHECK,
        "error_code is in error_codes_to_check",
        lambda a: Check(a.name, a.ports, error_codes_present(())),
    ),
    _check(
        "WouldAControllerRecoveryHelp",
        _CODE_CHECK,
        "a controller error a recovery may fix",
        lambda a: Check(a.name, a.ports, error_codes_present(CONTROLLER_RECOVERY_CODES)),
    ),
    _check(
        "WouldAPlannerRecoveryHelp",
        _CODE_CHECK,
        "a planner error a recovery may fix",
        lambda a: Check(a.name, a.ports, error_codes_present(PLANNER_RECOVERY_CODES)),
    ),
    _check(
        "WouldASmootherRecoveryHelp",
        _CODE_CHECK,
        "a smoother error a recovery may fix",
        lambda a: Check(a.name, a.ports, error_codes_present(SMOOTHER_RECOVERY_CODES)),
    ),
    _check(
        "ArePosesNear",
        (
            in_port("ref_pose", _POSE),
            in_port("target_pose", _POSE),
            in_port("tolerance", _F, "0.5"),
            in_port("global_frame", _S),
        ),
        "the two poses within tolerance",
        lambda a: Check(a.name, a.ports, poses_near),
    ),
)


def _retries(a: NodeArgs) -> int:
    n = a.ports.get_int("number_of_retries", 1)
    if n < 0:
        raise ValueError(f"number_of_retries must be >= 0, got {n}")
    return n


def _position(a: NodeArgs) -> tuple[float, float] | None:
    p = a.ctx.backend.robot_state().pose
    return None if p is None else (p.x, p.y)


_CONTROL: tuple[NodeSpec, ...] = (
    control(
        "PipelineSequence",
        lambda a: PipelineSequence(a.name, a.children),
        doc="earlier running children keep being ticked",
    ),
    control(
        "RecoveryNode",
        lambda a: RecoveryNode(a.children[0], a.children[1], _retries(a), name=a.name),
        (in_port("number_of_retries", _I, "1"),),
        "run the first child; on failure the second, then retry",
        children=(2, 2),
    ),
    control(
        "RoundRobin", lambda a: RoundRobin(a.name, a.children), doc="each start continues with the next child"
    ),
    decorator(
        "RateController",
        lambda a: RateController(a.name, a.children[0], a.ports.get_float("hz", 10.0), a.ctx.clock),
        (in_port("hz", _F, "10.0"),),
        "tick the child at most hz times per second",
    ),
    decorator(
        "DistanceController",
        lambda a: DistanceController(
            a.name, a.children[0], a.ports.get_float("distance", 1.0), lambda: _position(a)
        ),
        (in_port("distance", _F, "1.0"), *FRAME_PORTS),
        "tick the child each distance m travelled",
    ),
    decorator(
        "SpeedController",
        lambda a: SpeedController(
            a.name,
            a.children[0],
            a.ctx.clock,
            (a.ports.get_float("min_rate", 0.1), a.ports.get_float("max_rate", 1.0)),
            (a.ports.get_float("min_speed", 0.0), a.ports.get_float("max_speed", 0.5)),
            lambda: a.ctx.backend.robot_state().linear_velocity,
            lambda: (a.ports.get("goal"), a.ports.get("goals")),
        ),
        (
            in_port("min_rate", _F, "0.1"),
            in_port("max_rate", _F, "1.0"),
            in_port("min_speed", _F, "0.0"),
            in_port("max_speed", _F, "0.5"),
            *_GOALS_IN,
        ),
        "tick the child at a rate that grows with the robot's speed",
    ),
    decorator(
        "GoalUpdatedController",
        lambda a: GoalUpdatedController(
            a.name, a.children[0], lambda: (a.ports.get("goal"), a.ports.get("goals"))
        ),
        _GOALS_IN,
        "tick the child when the goal changed",
    ),
    decorator(
        "GoalUpdater",
        lambda a: BeforeTick(
            a.name, a.children[0], lambda: a.ports.put("output_goal", a.ports.get("input_goal"))
        ),
        (in_port("input_goal", _POSE), out_port("output_goal", _POSE)),
        "output_goal = input_goal (no goal update topic here), then tick the child",
    ),
    decorator(
        "SingleTrigger",
        lambda a: SingleTrigger(a.name, a.children[0]),
        doc="run the child once per activation",
    ),
    decorator(
        "PathLongerOnApproach",
        lambda a: PathLongerOnApproach(
            a.name,
            a.children[0],
            lambda: a.ports.get("path"),
            a.ports.get_float("prox_len", 3.0),
            a.ports.get_float("length_factor", 2.0),
        ),
        (in_port("path", _PATH), in_port("prox_len", _F, "3.0"), in_port("length_factor", _F, "2.0")),
        "tick the child when a new path near the goal is much longer",
    ),
)


#: Every Nav2 node of this registry.
NAV2_SPECS: tuple[NodeSpec, ...] = (*_CONTROL, *_ACTIONS, *_CONDITIONS)
