"""A stand-in for Nav2 Jazzy's ``nav2_simple_commander.BasicNavigator`` for the tests.

nav2_simple_commander is not published as a wheel, so the tests drive the simulator's Nav2
facade with this client, written for this project, which talks to Nav2 exactly the way
BasicNavigator (Jazzy) does: the same nav2_msgs action types on the same relative action
names under the navigator's namespace (``navigate_through_poses``, ``navigate_to_pose``,
``follow_waypoints``, ``spin``, ``backup``, ``drive_on_heading``, ``wait``, ...), lifecycle
``<node>/get_state`` polling until ``active``, an ``initialpose`` publisher and an
``amcl_pose`` subscription with transient-local durability, and the same public methods with
the same behavior (``waitUntilNav2Active``, ``goThroughPoses``, ``goToPose``,
``followWaypoints``, ``spin``, ``backup``, ``isTaskComplete``, ``getFeedback``,
``getResult``, ``cancelTask``). Each call spins the node itself, as BasicNavigator does.

It spins with an explicit executor bound to the node's own context, so several navigators
(one per robot) can live in one test process.
"""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from typing import Any

from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, PoseStamped, PoseWithCovarianceStamped
from lifecycle_msgs.srv import GetState
from nav2_msgs.action import (
    BackUp,
    ComputePathToPose,
    DriveOnHeading,
    FollowWaypoints,
    NavigateThroughPoses,
    NavigateToPose,
    Spin,
)
from nav2_msgs.srv import ClearEntireCostmap, ManageLifecycleNodes
from rclpy.action import ActionClient
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


class TaskResult(enum.Enum):
    UNKNOWN = 0
    SUCCEEDED = 1
    CANCELED = 2
    FAILED = 3


class Commander(Node):
    """BasicNavigator's client-side protocol, per namespace. ``timeout_s`` bounds every wait
    (BasicNavigator waits forever; a test must not): a hang guard, several times what
    discovery takes on a loaded 2-core machine."""

    def __init__(self, namespace: str, context: Context, timeout_s: float = 60.0) -> None:
        super().__init__("basic_navigator", namespace=namespace, context=context)
        self.timeout_s = timeout_s
        self._executor = SingleThreadedExecutor(context=context)
        self._executor.add_node(self)
        self.initial_pose = PoseStamped()
        self.initial_pose.header.frame_id = "map"
        self.goal_handle: Any = None
        self.result_future: Any = None
        self.feedback: Any = None
        self.status: int | None = None
        self.initial_pose_received = False
        self.last_amcl: Any = None
        self.amcl_count = 0
        qos = QoSProfile(
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
            history=HistoryPolicy.KEEP_LAST,
            depth=1,
        )
        self.clients_ = {
            "navigate_through_poses": ActionClient(self, NavigateThroughPoses, "navigate_through_poses"),
            "navigate_to_pose": ActionClient(self, NavigateToPose, "navigate_to_pose"),
            "follow_waypoints": ActionClient(self, FollowWaypoints, "follow_waypoints"),
            "spin": ActionClient(self, Spin, "spin"),
            "backup": ActionClient(self, BackUp, "backup"),
            "drive_on_heading": ActionClient(self, DriveOnHeading, "drive_on_heading"),
            "compute_path_to_pose": ActionClient(self, ComputePathToPose, "compute_path_to_pose"),
        }
        self.create_subscription(PoseWithCovarianceStamped, "amcl_pose", self._amcl_pose, qos)
        self.initial_pose_pub = self.create_publisher(PoseWithCovarianceStamped, "initialpose", 10)
        self.clear_global = self.create_client(
            ClearEntireCostmap, "global_costmap/clear_entirely_global_costmap"
        )

    # -- spinning helpers ---------------------------------------------------------------

    def _spin_until(self, future: Any, timeout_s: float | None = None) -> None:
        self._executor.spin_until_future_complete(
            future, timeout_sec=timeout_s if timeout_s is not None else self.timeout_s
        )

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Spin this node until ``predicate()`` is true; ``TimeoutError`` naming ``what``
        after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.get_namespace()}: {what} not within {timeout_s:.0f} s")
            self._executor.spin_once(timeout_sec=0.05)

    def _wait_server(self, key: str) -> None:
        deadline = time.monotonic() + self.timeout_s
        while not self.clients_[key].wait_for_server(timeout_sec=0.5):
            if time.monotonic() > deadline:
                raise TimeoutError(f"action server {self.get_namespace()}/{key} not available")

    def _send(self, key: str, goal: Any) -> bool:
        self._wait_server(key)
        fut = self.clients_[key].send_goal_async(goal, self._feedback_cb)
        self._spin_until(fut)
        if not fut.done():
            raise TimeoutError(f"no answer from {key} to a goal request")
        self.goal_handle = fut.result()
        self.status = None
        if not self.goal_handle.accepted:
            return False
        self.result_future = self.goal_handle.get_result_async()
        return True

    def _feedback_cb(self, msg: Any) -> None:
        self.feedback = msg.feedback

    def _amcl_pose(self, msg: Any) -> None:
        self.initial_pose_received = True
        self.last_amcl = msg
        self.amcl_count += 1

    def current_estimate(self) -> PoseStamped:
        """The robot's latest ``amcl_pose`` as a PoseStamped: the second one received, since
        the first may be the latched one from before the robot's last motion."""
        seen = self.amcl_count
        self.spin_until(lambda: self.amcl_count >= max(2, seen + 1), self.timeout_s, "a fresh amcl_pose")
        ps = PoseStamped()
        ps.header = self.last_amcl.header
        ps.pose = self.last_amcl.pose.pose
        return ps

    # -- BasicNavigator's API -----------------------------------------------------------

    def setInitialPose(self, initial_pose: PoseStamped) -> None:
        self.initial_pose_received = False
        self.initial_pose = initial_pose
        self._set_initial_pose()

    def _set_initial_pose(self) -> None:
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = self.initial_pose.header.frame_id
        msg.header.stamp = self.initial_pose.header.stamp
        msg.pose.pose = self.initial_pose.pose
        self.initial_pose_pub.publish(msg)

    def _wait_for_node_active(self, node_name: str) -> None:
        client = self.create_client(GetState, f"{node_name}/get_state")
        deadline = time.monotonic() + self.timeout_s
        while not client.wait_for_service(timeout_sec=0.5):
            if time.monotonic() > deadline:
                raise TimeoutError(f"{node_name}/get_state not available")
        state = "unknown"
        while state != "active":
            # one request at a time, polled until its reply or the deadline (BasicNavigator
            # polls the same way, without a deadline)
            fut = client.call_async(GetState.Request())
            self._spin_until(fut, max(0.0, deadline - time.monotonic()))
            if fut.result() is not None:
                state = fut.result().current_state.label
            if state != "active":
                if time.monotonic() > deadline:
                    raise TimeoutError(f"{node_name} never became active (last state {state!r})")
                self._executor.spin_once(timeout_sec=0.2)  # poll period while it is not active
        self.destroy_client(client)

    def waitUntilNav2Active(self, navigator: str = "bt_navigator", localizer: str = "amcl") -> None:
        self._wait_for_node_active(localizer)
        deadline = time.monotonic() + self.timeout_s
        while not self.initial_pose_received:
            self._set_initial_pose()  # republished until amcl_pose answers, as BasicNavigator does
            self._executor.spin_once(timeout_sec=0.5)
            if time.monotonic() > deadline:
                raise TimeoutError("amcl_pose never received")
        self._wait_for_node_active(navigator)

    def _manage_every_manager(self, command: int) -> dict[str, bool]:
        """Send ``command`` to every ``ManageLifecycleNodes`` service of the ROS graph, as
        BasicNavigator's lifecycleStartup / lifecycleShutdown do (every namespace's managers,
        not only this navigator's). Unlike BasicNavigator it waits for each answer (with the
        hang guard) and returns ``{service: success}``."""
        out: dict[str, bool] = {}
        for srv_name, srv_type in self.get_service_names_and_types():
            if srv_type[0] != "nav2_msgs/srv/ManageLifecycleNodes":
                continue
            mgr_client = self.create_client(ManageLifecycleNodes, srv_name)
            deadline = time.monotonic() + self.timeout_s
            while not mgr_client.wait_for_service(timeout_sec=1.0):
                if time.monotonic() > deadline:
                    raise TimeoutError(f"{srv_name} not available")
            req = ManageLifecycleNodes.Request()
            req.command = command
            future = mgr_client.call_async(req)
            self._spin_until(future)
            if future.result() is None:
                raise TimeoutError(f"no answer from {srv_name}")
            out[srv_name] = bool(future.result().success)
            self.destroy_client(mgr_client)
        return out

    def lifecycleStartup(self) -> dict[str, bool]:
        return self._manage_every_manager(ManageLifecycleNodes.Request.STARTUP)

    def lifecycleShutdown(self) -> dict[str, bool]:
        return self._manage_every_manager(ManageLifecycleNodes.Request.SHUTDOWN)

    def goThroughPoses(self, poses: list[PoseStamped], behavior_tree: str = "") -> bool:
        g = NavigateThroughPoses.Goal()
        g.poses = poses
        g.behavior_tree = behavior_tree
        return self._send("navigate_through_poses", g)

    def goToPose(self, pose: PoseStamped, behavior_tree: str = "") -> bool:
        g = NavigateToPose.Goal()
        g.pose = pose
        g.behavior_tree = behavior_tree
        return self._send("navigate_to_pose", g)

    def followWaypoints(self, poses: list[PoseStamped]) -> bool:
        g = FollowWaypoints.Goal()
        g.poses = poses
        return self._send("follow_waypoints", g)

    def spin(self, spin_dist: float = 1.57, time_allowance: int = 10) -> bool:
        g = Spin.Goal()
        g.target_yaw = float(spin_dist)
        g.time_allowance = Duration(sec=time_allowance)
        return self._send("spin", g)

    def backup(
        self, backup_dist: float = 0.15, backup_speed: float = 0.025, time_allowance: int = 10
    ) -> bool:
        g = BackUp.Goal()
        g.target = Point(x=float(backup_dist))
        g.speed = float(backup_speed)
        g.time_allowance = Duration(sec=time_allowance)
        return self._send("backup", g)

    def driveOnHeading(self, dist: float = 0.15, speed: float = 0.025, time_allowance: int = 10) -> bool:
        g = DriveOnHeading.Goal()
        g.target = Point(x=float(dist))
        g.speed = float(speed)
        g.time_allowance = Duration(sec=time_allowance)
        return self._send("drive_on_heading", g)

    def getPath(
        self, start: PoseStamped, goal: PoseStamped, planner_id: str = "", use_start: bool = False
    ) -> Any:
        g = ComputePathToPose.Goal()
        g.start, g.goal, g.planner_id, g.use_start = start, goal, planner_id, use_start
        if not self._send("compute_path_to_pose", g):
            return None
        self._spin_until(self.result_future)
        self.status = self.result_future.result().status
        if self.status != GoalStatus.STATUS_SUCCEEDED:
            return None
        return self.result_future.result().result.path

    def cancelTask(self) -> None:
        if self.result_future:
            fut = self.goal_handle.cancel_goal_async()
            self._spin_until(fut)

    def isTaskComplete(self) -> bool:
        if not self.result_future:
            return True
        self._spin_until(self.result_future, 0.10)
        res = self.result_future.result()
        if res is None:
            return False
        self.status = res.status
        return True

    def getFeedback(self) -> Any:
        return self.feedback

    def getResult(self) -> TaskResult:
        if self.status == GoalStatus.STATUS_SUCCEEDED:
            return TaskResult.SUCCEEDED
        if self.status == GoalStatus.STATUS_ABORTED:
            return TaskResult.FAILED
        if self.status == GoalStatus.STATUS_CANCELED:
            return TaskResult.CANCELED
        return TaskResult.UNKNOWN

    def result_message(self) -> Any:
        """The last finished task's result message (error_code, error_msg, ...)."""
        res = self.result_future.result() if self.result_future else None
        return None if res is None else res.result

    def close(self) -> None:
        for c in self.clients_.values():
            c.destroy()
        self._executor.remove_node(self)
        self._executor.shutdown(timeout_sec=1.0)
        self.destroy_node()
