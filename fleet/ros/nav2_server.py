"""Serve a :class:`~sim.simulator.Simulator` as namespaced Nav2 over real ROS 2 (rclpy).

For every robot namespace (``/robot1`` ...) one lean node ``/robot1/nav2_sim`` exposes what
a Nav2 Jazzy bringup under that namespace exposes to clients such as
``nav2_simple_commander.BasicNavigator(namespace='/robot1')``:

* action servers with Nav2's names and nav2_msgs types: ``navigate_through_poses``,
  ``navigate_to_pose``, ``follow_waypoints``, ``spin``, ``backup``, ``drive_on_heading``,
  ``wait``, ``follow_path`` (the path's poses are driven as NavigateThroughPoses),
  ``compute_path_to_pose`` and ``compute_path_through_poses`` (answered at once by the
  simulator's grid planner). Feedback is published at ``feedback_hz`` (wall), results carry
  Nav2's ``error_code`` / ``error_msg``; cancel ends a goal CANCELED; a new goal preempts the
  one the robot is executing, which ends ABORTED (one goal per robot, as in the simulator);
* lifecycle ``get_state`` services reporting ``active`` for ``bt_navigator``, ``amcl``,
  ``planner_server``, ``controller_server``, ``behavior_server`` and ``map_server``, and
  ``lifecycle_manager_navigation/manage_nodes`` (always succeeds);
* ``amcl_pose`` (``PoseWithCovarianceStamped``, transient local, depth 1: the simulator's
  true pose, since its localization is perfect) at ``amcl_hz`` and at once after each
  ``initialpose`` message (the hint is logged, the robot is not moved), ``odom``
  (``nav_msgs/Odometry``, frame ``odom`` = ``map`` in the simulator) and ``battery_state``
  (``sensor_msgs/BatteryState``: ``percentage`` in [0, 1], CHARGING on a charger) at
  ``odom_hz``;
* the costmap services ``{global,local}_costmap/clear_entirely_{global,local}_costmap``,
  ``local_costmap/clear_costmap_{except_region,around_robot,around_pose}`` (no-ops: the
  simulated costmaps hold only the static map) and ``{global,local}_costmap/get_costmap``
  (the static map: 254 for obstacles, 0 for free cells).

``profile="lean"`` serves only the seven navigation actions the fleet uses, the lifecycle
services and amcl_pose/odom/initialpose (for many robots per process).

Threading: everything (ROS callbacks, stepping the simulator) runs on one thread, in one
``SingleThreadedExecutor``; execute callbacks are coroutines that await the simulator's
verdict, so the simulator is never touched concurrently. Simulated time advances with wall
time times ``speed`` (the only wall-clock reads are for that pacing).

Command line: ``python -m fleet.ros.nav2_server CONFIG [--robots N] [--speed X] ...`` (and
``fleet sim-ros CONFIG``); see :func:`main`. It stops cleanly on SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleet.ros.env import apply_ros_env_defaults

apply_ros_env_defaults()

import rclpy  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from lifecycle_msgs.msg import State  # noqa: E402
from lifecycle_msgs.srv import GetState  # noqa: E402
from nav2_msgs.msg import Costmap  # noqa: E402
from nav2_msgs.srv import (  # noqa: E402
    ClearCostmapAroundPose,
    ClearCostmapAroundRobot,
    ClearCostmapExceptRegion,
    ClearEntireCostmap,
    GetCostmap,
    ManageLifecycleNodes,
)
from nav_msgs.msg import Odometry  # noqa: E402
from nav_msgs.msg import Path as PathMsg  # noqa: E402
from rclpy.action import ActionServer, CancelResponse, GoalResponse  # noqa: E402
from rclpy.action.server import ServerGoalHandle  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from rclpy.task import Future  # noqa: E402

try:
    from sensor_msgs.msg import BatteryState
except ImportError:  # optional: without it no battery_state is published
    BatteryState = None

from fleet.errors import BackendError, FleetError  # noqa: E402
from fleet.ros.conversions import (  # noqa: E402
    ACTION_TYPES,
    AMCL_POSE_QOS,
    NAVIGATION_ACTIONS,
    feedback_to_msg,
    msg_to_goal,
    pose2d_to_pose,
    pose2d_to_pose_stamped,
    pose_stamped_to_pose2d,
    result_to_msg,
    seconds_to_duration,
    seconds_to_time,
)
from fleet.types import ErrorCode, Feedback, GoalState, GoalStatus, NavigateThroughPoses, Pose2D  # noqa: E402

#: Action servers of the "full" profile (Nav2's names); "lean" serves the navigation ones.
FULL_ACTIONS = tuple(ACTION_TYPES)
LEAN_ACTIONS = NAVIGATION_ACTIONS
LIFECYCLE_NODES = (
    "bt_navigator",
    "amcl",
    "planner_server",
    "controller_server",
    "behavior_server",
    "map_server",
)
#: follow_path drives the path's poses spaced at least this far apart (m).
FOLLOW_PATH_SPACING_M = 0.5
#: Nav2's ComputePathThroughPoses codes are the ComputePathToPose codes + 100.
THROUGH_POSES_CODE_OFFSET = 100


@dataclass
class _Active:
    """One goal the simulator is executing for a ROS client."""

    goal_id: str
    kind: str
    handle: ServerGoalHandle
    done: Future
    poses: tuple[Pose2D, ...] = ()
    t0: float = 0.0
    last_feedback: float = field(default=-1.0)


class _RobotFacade:
    """Nav2's client-facing interface of one simulated robot (one node under its namespace)."""

    def __init__(self, server: Nav2SimServer, namespace: str, context: Context, profile: str) -> None:
        self.server = server
        self.sim = server.sim
        self.ns = namespace
        self.node = Node(
            "nav2_sim",
            namespace=namespace,
            context=context,
            start_parameter_services=False,
            enable_rosout=False,
        )
        self.active: dict[str, _Active] = {}
        actions = FULL_ACTIONS if profile == "full" else LEAN_ACTIONS
        self.action_servers = [
            ActionServer(
                self.node,
                ACTION_TYPES[kind],
                kind,
                execute_callback=self._make_execute(kind),
                goal_callback=lambda _req: GoalResponse.ACCEPT,
                cancel_callback=lambda _h: CancelResponse.ACCEPT,
            )
            for kind in actions
        ]
        for name in LIFECYCLE_NODES:
            self.node.create_service(GetState, f"{name}/get_state", self._get_state)
        self.node.create_service(
            ManageLifecycleNodes, "lifecycle_manager_navigation/manage_nodes", self._manage
        )
        if profile == "full":
            self.node.create_service(
                ClearEntireCostmap, "global_costmap/clear_entirely_global_costmap", self._clear
            )
            self.node.create_service(
                ClearEntireCostmap, "local_costmap/clear_entirely_local_costmap", self._clear
            )
            self.node.create_service(
                ClearCostmapExceptRegion, "local_costmap/clear_costmap_except_region", self._clear
            )
            self.node.create_service(
                ClearCostmapAroundRobot, "local_costmap/clear_costmap_around_robot", self._clear
            )
            self.node.create_service(
                ClearCostmapAroundPose, "local_costmap/clear_costmap_around_pose", self._clear
            )
            self.node.create_service(GetCostmap, "global_costmap/get_costmap", self._get_costmap)
            self.node.create_service(GetCostmap, "local_costmap/get_costmap", self._get_costmap)
        self.amcl_pub = self.node.create_publisher(PoseWithCovarianceStamped, "amcl_pose", AMCL_POSE_QOS)
        self.odom_pub = self.node.create_publisher(Odometry, "odom", 10)
        self.battery_pub = None
        if BatteryState is not None:
            self.battery_pub = self.node.create_publisher(BatteryState, "battery_state", 10)
        self.node.create_subscription(PoseWithCovarianceStamped, "initialpose", self._initial_pose, 10)
        self.initial_poses = 0

    # -- services -------------------------------------------------------------------------

    def _get_state(self, _req: Any, resp: Any) -> Any:
        resp.current_state = State(id=State.PRIMARY_STATE_ACTIVE, label="active")
        return resp

    def _manage(self, _req: Any, resp: Any) -> Any:
        resp.success = True
        return resp

    def _clear(self, _req: Any, resp: Any) -> Any:
        return resp

    def _get_costmap(self, _req: Any, resp: Any) -> Any:
        resp.map = self.server.costmap_msg()
        return resp

    def _initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.initial_poses += 1
        hint = pose_stamped_to_pose2d(msg.pose)  # type: ignore[arg-type]
        pose = self.sim.robot_state(self.ns).pose
        if pose is not None and pose.distance_to(hint) > 0.5:
            self.node.get_logger().info(
                f"initialpose ({hint.x:.2f}, {hint.y:.2f}) ignored: the simulated robot is at "
                f"({pose.x:.2f}, {pose.y:.2f})"
            )
        self.publish_pose()

    # -- topics ---------------------------------------------------------------------------

    def publish_pose(self) -> None:
        st = self.sim.robot_state(self.ns)
        if st.pose is None:
            return
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "map"
        msg.header.stamp = self.server.stamp()
        msg.pose.pose = pose2d_to_pose(st.pose)
        cov = [0.0] * 36
        cov[0] = cov[7] = 0.0025
        cov[35] = 0.0007
        msg.pose.covariance = cov
        self.amcl_pub.publish(msg)

    def publish_odom(self) -> None:
        st = self.sim.robot_state(self.ns)
        if st.pose is None:
            return
        msg = Odometry()
        msg.header.frame_id = "odom"
        msg.header.stamp = self.server.stamp()
        msg.child_frame_id = "base_link"
        msg.pose.pose = pose2d_to_pose(st.pose)
        msg.twist.twist.linear.x = float(st.linear_velocity)
        msg.twist.twist.angular.z = float(st.angular_velocity)
        self.odom_pub.publish(msg)
        if self.battery_pub is not None:
            b = BatteryState()
            b.header.stamp = msg.header.stamp
            b.percentage = float(st.battery)
            b.present = True
            b.power_supply_status = (
                BatteryState.POWER_SUPPLY_STATUS_CHARGING
                if st.charging
                else BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
            )
            self.battery_pub.publish(b)

    # -- actions --------------------------------------------------------------------------

    def _make_execute(self, kind: str) -> Any:
        async def execute(goal_handle: ServerGoalHandle) -> Any:
            return await self._execute(kind, goal_handle)

        return execute

    def _invalid(self, kind: str, req: Any) -> tuple[int, str] | None:
        if kind in ("backup", "drive_on_heading"):
            code = ErrorCode.BACKUP_INVALID_INPUT if kind == "backup" else ErrorCode.DRIVE_INVALID_INPUT
            if req.target.y != 0.0 or req.target.z != 0.0:
                return int(
                    code
                ), "Only forward/backward motion along x is supported (target.y and target.z must be 0)."
            if kind == "drive_on_heading" and req.target.x * req.speed < 0.0:
                return int(code), "Speed and target distance must have the same sign."
        return None

    async def _execute(self, kind: str, goal_handle: ServerGoalHandle) -> Any:
        req = goal_handle.request
        if kind in ("compute_path_to_pose", "compute_path_through_poses"):
            return self._compute_path(kind, goal_handle)
        invalid = self._invalid(kind, req)
        if invalid is not None:
            result = ACTION_TYPES[kind].Result()
            result.error_code, result.error_msg = invalid
            goal_handle.abort()
            return result
        poses: tuple[Pose2D, ...]
        if kind == "follow_path":
            poses = _thin_path([pose_stamped_to_pose2d(p) for p in req.path.poses], FOLLOW_PATH_SPACING_M)
            goal: Any = NavigateThroughPoses(poses)
        else:
            goal = msg_to_goal(kind, req)
            poses = tuple(getattr(goal, "poses", ()) or ((goal.pose,) if hasattr(goal, "pose") else ()))
        gid = self.sim.send_goal(self.ns, goal)
        active = _Active(gid, kind, goal_handle, Future(), poses, self.sim.clock.now())
        self.active[gid] = active
        self.poll(active, time.monotonic())
        await active.done
        state: GoalState = active.done.result()
        result = result_to_msg(kind, state, poses, self.sim.clock.now() - active.t0)
        if state.status is GoalStatus.SUCCEEDED:
            goal_handle.succeed()
        elif state.status is GoalStatus.CANCELED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return result

    def poll(self, active: _Active, wall: float) -> None:
        """Forward a cancel request, publish due feedback, resolve a finished goal."""
        if active.done.done():
            return
        if active.handle.is_cancel_requested:
            self.sim.cancel_goal(active.goal_id)
        state = self.sim.goal_state(active.goal_id)
        if state.status.terminal:
            self.active.pop(active.goal_id, None)
            active.done.set_result(state)
            return
        fb_period = self.server.feedback_period
        if fb_period is not None and wall - active.last_feedback >= fb_period and active.handle.is_active:
            active.last_feedback = wall
            fb = state.feedback
            if active.kind == "follow_path":
                fb = Feedback(distance_remaining_m=fb.distance_remaining_m)
            active.handle.publish_feedback(feedback_to_msg(active.kind, fb, self.server.stamp()))

    def _compute_path(self, kind: str, goal_handle: ServerGoalHandle) -> Any:
        req = goal_handle.request
        result = ACTION_TYPES[kind].Result()
        t0 = time.monotonic()
        if req.use_start:
            start = pose_stamped_to_pose2d(req.start)
        else:
            pose = self.sim.robot_state(self.ns).pose
            start = pose if pose is not None else Pose2D(0.0, 0.0)
        goals = (
            [pose_stamped_to_pose2d(req.goal)]
            if kind == "compute_path_to_pose"
            else [pose_stamped_to_pose2d(p) for p in req.goals]
        )
        offset = 0 if kind == "compute_path_to_pose" else THROUGH_POSES_CODE_OFFSET
        if not goals:
            result.error_code, result.error_msg = 309, "No goals were given."
            goal_handle.abort()
            return result
        points: list[tuple[float, float]] = []
        cur = (start.x, start.y)
        for g in goals:
            plan = self.sim.planner.plan(cur, (g.x, g.y))
            if not plan.ok:
                result.error_code = int(plan.error_code) + offset
                result.error_msg = plan.error_msg
                goal_handle.abort()
                return result
            pts = list(plan.path)
            points.extend(pts if not points else pts[1:])
            cur = (g.x, g.y)
        path = PathMsg()
        path.header.frame_id = "map"
        path.header.stamp = self.server.stamp()
        final_yaw = goals[-1].theta
        out = []
        for i, (x, y) in enumerate(points):
            if i + 1 < len(points):
                yaw = math.atan2(points[i + 1][1] - y, points[i + 1][0] - x)
            else:
                yaw = final_yaw
            out.append(pose2d_to_pose_stamped(Pose2D(x, y, yaw), path.header.stamp))
        path.poses = out
        result.path = path
        result.planning_time = seconds_to_duration(time.monotonic() - t0)
        goal_handle.succeed()
        return result

    def destroy(self) -> None:
        for a in self.action_servers:
            a.destroy()
        self.node.destroy_node()


def _thin_path(poses: list[Pose2D], spacing: float) -> tuple[Pose2D, ...]:
    """Keep poses at least ``spacing`` apart (always the last one)."""
    if not poses:
        return ()
    out = [poses[0]]
    for p in poses[1:-1]:
        if p.distance_to(out[-1]) >= spacing:
            out.append(p)
    if len(poses) > 1:
        out.append(poses[-1])
    return tuple(out[1:] if len(out) > 1 and out[0].distance_to(out[1]) < spacing else out)


class Nav2SimServer:
    """Serve ``sim`` as namespaced Nav2 for ``namespaces`` (default: every robot of the sim).

    Args:
        sim: the simulator; this server is its only user while it runs (it steps it).
        namespaces: robots to serve (each must be in the simulator).
        speed: simulated seconds per wall second; ``0`` pauses the world.
        feedback_hz, odom_hz, amcl_hz: wall-clock publication rates (``0`` disables).
        profile: ``"full"`` (every Nav2 interface listed in the module docstring) or
            ``"lean"`` (the seven navigation actions, lifecycle, amcl_pose/odom).
        context: an initialized rclpy ``Context``; by default the server creates and owns one.
        domain_id: ROS domain of the context it creates (default: ``ROS_DOMAIN_ID``).

    Call :meth:`spin` (blocks until :meth:`request_stop` or a signal handler stops it) or
    :meth:`spin_once` in your own loop, then :meth:`close`.
    """

    def __init__(
        self,
        sim: Any,
        namespaces: list[str] | None = None,
        *,
        speed: float = 1.0,
        feedback_hz: float = 10.0,
        odom_hz: float = 10.0,
        amcl_hz: float = 1.0,
        profile: str = "full",
        context: Context | None = None,
        domain_id: int | None = None,
    ) -> None:
        if profile not in ("full", "lean"):
            raise BackendError(f"profile must be 'full' or 'lean', got {profile!r}")
        if speed < 0:
            raise BackendError(f"speed must be >= 0, got {speed}")
        self.sim = sim
        self.speed = float(speed)
        self.feedback_period = 1.0 / feedback_hz if feedback_hz > 0 else None
        self._owns_context = context is None
        if context is None:
            context = Context()
            rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.context = context
        self.executor = SingleThreadedExecutor(context=context)
        self._stop = False
        self._costmap: Costmap | None = None
        self._t_create = time.monotonic()
        self.world = Node("fleet_sim", context=context, start_parameter_services=False, enable_rosout=False)
        self.robots: dict[str, _RobotFacade] = {}
        for ns in namespaces if namespaces is not None else list(sim.namespaces):
            sim.robot_state(ns)  # raises BackendError for an unknown robot
            self.robots[ns] = _RobotFacade(self, ns, context, profile)
        self.create_time_s = time.monotonic() - self._t_create
        self.executor.add_node(self.world)
        for r in self.robots.values():
            self.executor.add_node(r.node)
        self._wall_last = time.monotonic()
        self._sim_debt = 0.0
        step = sim.params.step_s
        self.world.create_timer(max(step / self.speed, 0.01) if self.speed > 0 else 0.05, self._tick)
        if odom_hz > 0:
            self.world.create_timer(1.0 / odom_hz, self._publish_odom)
        if amcl_hz > 0:
            self.world.create_timer(1.0 / amcl_hz, self._publish_amcl)
        self._publish_amcl()

    # -- time -----------------------------------------------------------------------------

    def stamp(self) -> Any:
        """Header stamps carry simulated time."""
        return seconds_to_time(self.sim.clock.now())

    def _tick(self) -> None:
        wall = time.monotonic()
        self._sim_debt += (wall - self._wall_last) * self.speed
        self._wall_last = wall
        step = self.sim.params.step_s
        n = 0
        while self._sim_debt >= step - 1e-9 and n < 20:
            self.sim.step()
            self._sim_debt -= step
            n += 1
        if n == 20:
            self._sim_debt = 0.0  # cannot keep up: drop the backlog rather than spiral
        for r in self.robots.values():
            for a in list(r.active.values()):
                r.poll(a, wall)

    def _publish_odom(self) -> None:
        for r in self.robots.values():
            r.publish_odom()

    def _publish_amcl(self) -> None:
        for r in self.robots.values():
            r.publish_pose()

    def costmap_msg(self) -> Costmap:
        if self._costmap is None:
            import numpy as np

            from fleet.maps import FREE

            g = self.sim.grid
            m = Costmap()
            m.header.frame_id = "map"
            m.metadata.layer = "master"
            m.metadata.resolution = float(g.resolution)
            m.metadata.size_x = g.width
            m.metadata.size_y = g.height
            m.metadata.origin = pose2d_to_pose(Pose2D(g.origin_x, g.origin_y, 0.0))
            m.data = np.where(g.cells == FREE, 0, 254).astype(np.uint8).ravel().tolist()
            self._costmap = m
        return self._costmap

    # -- running --------------------------------------------------------------------------

    def spin_once(self, timeout_s: float = 0.1) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def request_stop(self) -> None:
        """Make :meth:`spin` return (safe from a signal handler or another thread)."""
        self._stop = True

    def spin(self) -> None:
        while not self._stop and self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        """Abort nothing, destroy every node, shut the context down (if the server owns it)."""
        for r in self.robots.values():
            r.destroy()
        self.world.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        if self._owns_context and self.context.ok():
            rclpy.shutdown(context=self.context)

    @property
    def served(self) -> list[str]:
        return list(self.robots)


def build_simulator(config_path: str, robots: int | None = None) -> Any:
    """Load a fleet config and make a simulator with its robots (``robots`` overrides the count)."""
    from fleet.clock import SimClock
    from fleet.config.loader import load_config
    from sim.simulator import Simulator

    cfg = load_config(config_path, robots=robots)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    for spec in cfg.robots:
        sim.add_robot(spec)
    return sim


def main(argv: list[str] | None = None) -> int:
    """``fleet sim-ros CONFIG``: serve the config's simulated robots as namespaced Nav2."""
    ap = argparse.ArgumentParser(
        prog="fleet sim-ros",
        description=(
            "Serve the simulated fleet of CONFIG as namespaced Nav2 over ROS 2: for every robot "
            "/NAME, the Nav2 action servers (navigate_to_pose, navigate_through_poses, "
            "follow_waypoints, spin, backup, ...), lifecycle get_state, amcl_pose, odom and the "
            "costmap services. nav2_simple_commander's BasicNavigator(namespace='/robot1') "
            "works against it. Stop with Ctrl-C."
        ),
    )
    ap.add_argument("config", help="fleet config YAML (see docs/config.md)")
    ap.add_argument("--robots", type=int, default=None, help="serve N robots instead of the config's list")
    ap.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall second (default 1)")
    ap.add_argument(
        "--profile", choices=("full", "lean"), default="full", help="which Nav2 interfaces to serve"
    )
    ap.add_argument("--feedback-hz", type=float, default=10.0, help="action feedback rate (wall Hz)")
    ap.add_argument("--odom-hz", type=float, default=10.0, help="odom rate (wall Hz, 0 = off)")
    ap.add_argument("--amcl-hz", type=float, default=1.0, help="amcl_pose rate (wall Hz, 0 = off)")
    ap.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: the environment's)")
    ap.add_argument("--ready-file", default=None, help="write a JSON line here once every server exists")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many wall seconds")
    args = ap.parse_args(argv)

    if args.domain_id is not None:
        apply_ros_env_defaults(args.domain_id)
    try:
        sim = build_simulator(args.config, args.robots)
    except FleetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return serve(
        sim,
        speed=args.speed,
        feedback_hz=args.feedback_hz,
        odom_hz=args.odom_hz,
        amcl_hz=args.amcl_hz,
        profile=args.profile,
        domain_id=args.domain_id,
        ready_file=args.ready_file,
        duration_s=args.duration,
    )


def serve(
    sim: Any,
    *,
    ready_file: str | None = None,
    duration_s: float | None = None,
    **server_kwargs: Any,
) -> int:
    """Serve ``sim`` (see :class:`Nav2SimServer` for ``server_kwargs``) until SIGINT/SIGTERM or
    ``duration_s`` wall seconds. Writes ``ready_file`` (JSON: pid, robots, create_s) once every
    server exists. Returns the process exit status (0)."""
    t0 = time.monotonic()
    server = Nav2SimServer(sim, **server_kwargs)

    def _stop(_sig: int, _frm: Any) -> None:
        server.request_stop()

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    info = {
        "pid": os.getpid(),
        "robots": server.served,
        "create_s": round(time.monotonic() - t0, 3),
        "domain_id": os.environ.get("ROS_DOMAIN_ID", "0"),
    }
    print(
        f"[sim-ros] serving {len(server.served)} robots as namespaced Nav2 (created in {info['create_s']} s, "
        f"ROS_DOMAIN_ID={info['domain_id']}); Ctrl-C stops",
        flush=True,
    )
    if ready_file:
        tmp = Path(ready_file + ".tmp")
        tmp.write_text(json.dumps(info) + "\n")
        tmp.replace(ready_file)
    end = None if duration_s is None else time.monotonic() + duration_s
    try:
        while not server._stop and server.context.ok():
            server.spin_once(0.1)
            if end is not None and time.monotonic() >= end:
                break
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
