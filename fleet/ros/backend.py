"""The ROS 2 navigation backend: :class:`~fleet.navigation.NavigationBackend` over any
namespaced Nav2 (a real Nav2 Jazzy bringup, or ``fleet sim-ros``).

One :class:`RosNavigationBackend` per robot namespace, all sharing one rclpy context, one lean
node per robot (``<ns>/fleet_backend``) and one executor spinning on a background thread
(:class:`RosBackends`, made by :func:`make_ros_backends`). Under the robot's namespace it uses
the Nav2 action servers named like the goal kinds (``navigate_to_pose``,
``navigate_through_poses``, ``follow_waypoints``, ``spin``, ``backup``, ``drive_on_heading``,
``wait``) and the topics ``amcl_pose`` (map pose), ``odom`` (velocities, and the pose between
two amcl updates) and, if present, ``battery_state``.

Mapping onto the protocol (:mod:`fleet.navigation`):

* :meth:`~RosNavigationBackend.send_goal` never blocks: it records the goal ``PENDING``, hands
  the request to the executor thread and returns an id ``"<ns>#r<n>"`` (never reused). The
  goal becomes ``EXECUTING`` when the server accepts it, ``REJECTED`` if it refuses.
* Preemption: the motion goal this backend was running ends ``ABORTED`` at once when a new
  motion goal is sent (error message names the new goal); if it ran on another action server,
  a cancel request is sent to that server so the robot executes one goal at a time.
  Computation goals (``compute_path_to_pose``, ``compute_path_through_poses``,
  ``smooth_path``: Nav2's planner and smoother servers; ``clear_costmaps``: the
  ``clear_entirely_{global,local}_costmap`` services) run beside it, their clients made on
  first use (as those not ``eager``). A planner's or smoother's path is the terminal ``path``.
* Results: Nav2's status and ``error_code`` / ``error_msg`` (FollowWaypoints: missed waypoint
  indices) become the terminal :class:`~fleet.types.GoalState`; feedback messages become
  :class:`~fleet.types.Feedback`.
* :meth:`~RosNavigationBackend.cancel_goal` is idempotent; the goal is ``CANCELING`` until
  the server confirms ``CANCELED``.
* ``goal_state`` answers the last :data:`KEEP_GOALS` goals (older ids raise ``KeyError``,
  as for an id never issued), so a long run's memory stays bounded.
* Lifecycle: :func:`make_ros_backends` with ``wait_s`` waits until every robot's navigator
  is active (bringing unconfigured robots up through their lifecycle managers); a robot whose
  ``bt_navigator`` stops answering ``active`` reports ``navigation_ready = False`` (the
  agent's safety watchdog then stops it).
* Server loss: a goal whose action server is not discovered any more (or that got no answer
  to its request) for ``server_timeout_s`` ends ``ABORTED`` with
  ``ErrorCode.SERVER_UNAVAILABLE``; nothing waits forever.

Thread safety: the backend methods may be called from any one thread (the runner's); ROS
callbacks run on the executor thread; shared state is guarded by one lock.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Protocol

import numpy as np

from fleet.ros.env import apply_ros_env_defaults

apply_ros_env_defaults()

import rclpy  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402
from nav2_msgs.srv import ClearEntireCostmap  # noqa: E402
from rclpy.action.client import ActionClient, ClientGoalHandle  # noqa: E402
from rclpy.client import Client  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from rclpy.task import Future  # noqa: E402

from fleet.errors import BackendError  # noqa: E402
from fleet.ros.action_graph import LEAN_NODE_PARAMETERS, OWN_NODES, served_actions  # noqa: E402
from fleet.ros.conversions import (  # noqa: E402
    ACTION_TYPES,
    CLEAR_COSTMAP_SERVICES,
    NAVIGATION_ACTIONS,
    PLANNING_ACTIONS,
    FeedbackMsg,
    goal_to_msg,
    msg_to_feedback,
    result_path,
)
from fleet.ros.lifecycle_client import LifecycleWatch  # noqa: E402
from fleet.ros.remote_goal import STATUS_MAP, RemoteGoal, succeed_when_answered  # noqa: E402
from fleet.ros.robot_state import RobotStateTracker  # noqa: E402
from fleet.types import (  # noqa: E402
    MOTION_GOAL_KINDS,
    ClearCostmaps,
    Costmap,
    ErrorCode,
    Goal,
    GoalState,
    GoalStatus,
    RobotState,
)

#: Goal kinds (= Nav2 action names) whose servers the backend waits for at start.
BACKEND_KINDS = NAVIGATION_ACTIONS
#: Every goal kind the backend sends (the last is a service call).
SENT_KINDS = (*NAVIGATION_ACTIONS, *PLANNING_ACTIONS, "clear_costmaps")
#: A robot whose odometry lags the newest stamp by more than this (s) does not hold the
#: fleet's clock back (:meth:`RosBackends.fleet_time`).
CLOCK_LAG_S = 2.0
#: Wall seconds between checks that a robot's action servers are discovered (navigation_ready).
READY_PERIOD_S = 1.0
#: Wall seconds :meth:`RosBackends.close` waits for queued requests and cancel answers.
CLOSE_FLUSH_S = 3.0
#: Goals kept for ``goal_state`` (the oldest beyond are forgotten: ``KeyError``).
KEEP_GOALS = 4096
#: Goal kinds that move the robot along the floor (for the progress checker).
DRIVING_KINDS = frozenset({"navigate_to_pose", "navigate_through_poses", "follow_waypoints"})


class _FeedbackMessage(Protocol):
    """What an action client's feedback callback receives (``<Action>.Impl.FeedbackMessage``)."""

    feedback: FeedbackMsg


class RosNavigationBackend:
    """NavigationBackend of one namespaced Nav2 robot. Made by :func:`make_ros_backends`;
    see the module docstring for the contract mapping."""

    def __init__(self, owner: RosBackends, namespace: str, server_timeout_s: float, index: int = 0) -> None:
        self._owner = owner
        self._ns = namespace
        self._timeout = server_timeout_s
        self._lock = owner.lock
        self.node = Node(
            "fleet_backend",
            namespace=namespace,
            context=owner.context,
            start_parameter_services=False,
            enable_rosout=False,
            parameter_overrides=LEAN_NODE_PARAMETERS,
        )
        self._clients = {k: ActionClient(self.node, ACTION_TYPES[k], k) for k in owner.eager}
        self._services: dict[str, Client] = {}
        self._goals: dict[str, RemoteGoal] = {}
        self._live: dict[str, RemoteGoal] = {}
        self._ids = itertools.count(1)
        self._current: RemoteGoal | None = None
        #: Whether every action server of the robot is discovered (read for the whole fleet
        #: every :data:`READY_PERIOD_S`, every 0.1 s while :meth:`_sweep_wanted`).
        self.servers_ready = False
        #: The action and service servers seen in the robot's namespace at the last sweep.
        self.served: frozenset[str] = frozenset()
        #: The robot's navigator lifecycle state (polled on the executor thread).
        self.lifecycle = LifecycleWatch(self.node, lambda name: name in self.served)
        self.tracker = RobotStateTracker(
            self.node,
            self._lock,
            owner.saw_stamp,
            owner.fleet_time,
            self._driving,
            saw_odom=lambda t: owner.saw_odom(index, t),
        )

    # -- protocol -------------------------------------------------------------------------

    @property
    def namespace(self) -> str:
        return self._ns

    def send_goal(self, goal: Goal) -> str:
        """Record ``goal`` PENDING, queue it for the executor thread, return its id at once."""
        if getattr(goal, "kind", None) not in SENT_KINDS:
            raise BackendError(f"{self._ns}: the ROS backend cannot send a {type(goal).__name__} goal")
        gid = f"{self._ns}#r{next(self._ids)}"
        rec = RemoteGoal(gid, goal.kind, goal, sent_at=time.monotonic())
        with self._lock:
            old = self._current
            self._goals[gid] = rec
            self._live[gid] = rec
            while len(self._goals) > KEEP_GOALS:  # the book is bounded: the oldest goes
                self._goals.pop(next(iter(self._goals)))
            cancel_old = None
            if goal.kind not in MOTION_GOAL_KINDS:
                old = None  # a computation runs beside the motion goal
            else:
                self._current = rec
            if old is not None and not old.status.terminal:
                old.finish(GoalStatus.ABORTED, 0, f"Goal {old.goal_id} was preempted by goal {gid}.")
                if old.kind != goal.kind:
                    cancel_old = old
        if cancel_old is not None:
            self._owner.call_soon(lambda: self._cancel_remote(cancel_old))
        self._owner.call_soon(lambda: self._send_remote(rec))
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        with self._lock:
            return self._goals[goal_id].snapshot()

    def cancel_goal(self, goal_id: str) -> None:
        with self._lock:
            rec = self._goals.get(goal_id)
            if rec is None or rec.status.terminal or rec.cancel_wanted:
                return
            rec.cancel_wanted = True
            if rec.status is GoalStatus.EXECUTING:
                rec.status = GoalStatus.CANCELING
        self._owner.call_soon(lambda: self._cancel_remote(rec))

    def robot_state(self) -> RobotState:
        """Pose, velocities, battery, distance, stuck and localization from the robot's topics
        (see :mod:`fleet.ros.robot_state`); ``navigation_ready`` while its action servers are
        discovered and its ``bt_navigator`` answers ``active`` (:mod:`fleet.ros.lifecycle_client`,
        polled every second)."""
        st = self.tracker.state()
        if not self.servers_ready:
            return dataclasses.replace(st, navigation_ready=False)
        return st

    def _driving(self) -> bool:
        """Whether the running goal should move the robot (lock held by the caller)."""
        cur = self._current
        return cur is not None and not cur.status.terminal and cur.kind in DRIVING_KINDS

    def __repr__(self) -> str:
        return f"RosNavigationBackend({self._ns!r})"

    # -- executor thread ------------------------------------------------------------------

    def _client(self, kind: str) -> ActionClient:
        """The action client of ``kind`` (created on first use; executor thread)."""
        client = self._clients.get(kind)
        if client is None:
            client = self._clients[kind] = ActionClient(self.node, ACTION_TYPES[kind], kind)
        return client

    def _ready(self, kind: str) -> bool:
        """Whether the server(s) of goal kind ``kind`` are discovered (executor thread)."""
        if kind == "clear_costmaps":
            return all(self._service(n).service_is_ready() for n in CLEAR_COSTMAP_SERVICES.values())
        return kind in self.served  # the fleet's graph sweep (RosBackends._tick)

    def _sweep_wanted(self) -> bool:
        """Whether this robot's servers should be looked up again now: its navigator is active
        but a server is missing, or a live goal's server is not seen (executor thread)."""
        with self._lock:
            kinds = {r.kind for r in self._live.values()}
        return (self.lifecycle.active and not self.servers_ready) or not kinds <= self.served

    def _service(self, name: str) -> Client:
        client = self._services.get(name)
        if client is None:
            client = self._services[name] = self.node.create_client(ClearEntireCostmap, name)
        return client

    def _clear_costmaps(self, rec: RemoteGoal) -> None:
        """Call the clear services of the goal's costmaps; the goal SUCCEEDS when all answered."""
        assert isinstance(rec.goal, ClearCostmaps)
        which = Costmap(rec.goal.costmap)
        names = [n for c, n in CLEAR_COSTMAP_SERVICES.items() if which in (Costmap.BOTH, c)]
        calls = [self._service(n).call_async(ClearEntireCostmap.Request()) for n in names]
        succeed_when_answered(rec, calls, self._lock)

    def _send_remote(self, rec: RemoteGoal) -> None:
        with self._lock:
            # sent already: send_goal queues this call and the watchdog may run first
            if rec.status.terminal or rec.handle is not None:
                return
        if not self._ready(rec.kind):
            return  # the watchdog retries, then gives up after server_timeout_s
        if rec.kind == "clear_costmaps":
            self._clear_costmaps(rec)
            return
        client = self._client(rec.kind)
        if not client.server_is_ready():
            return  # the watchdog retries, then gives up after server_timeout_s
        rec.sent_at = time.monotonic()
        fut = client.send_goal_async(
            goal_to_msg(rec.goal), feedback_callback=lambda m: self._on_feedback(rec, m)
        )
        rec.handle = fut  # marks "request sent"
        fut.add_done_callback(lambda f: self._on_goal_response(rec, f))

    def _on_goal_response(self, rec: RemoteGoal, fut: Future) -> None:
        handle: ClientGoalHandle | None = fut.result() if fut.exception() is None else None
        cancel = False
        with self._lock:
            if handle is None or not handle.accepted:
                rec.finish(GoalStatus.REJECTED, 0, f"{self._ns}/{rec.kind} rejected the goal")
                return
            rec.handle = handle
            if rec.status is GoalStatus.PENDING:
                rec.status = GoalStatus.CANCELING if rec.cancel_wanted else GoalStatus.EXECUTING
            # preempted or canceled before the server answered: cancel it there too
            cancel = rec.cancel_wanted or rec.status.terminal
        if cancel:
            self._owner.track_cancel(handle.cancel_goal_async())
        handle.get_result_async().add_done_callback(lambda f: self._on_result(rec, f))

    def _on_feedback(self, rec: RemoteGoal, msg: _FeedbackMessage) -> None:
        fb = msg_to_feedback(rec.kind, msg.feedback)
        with self._lock:
            if not rec.status.terminal:
                rec.feedback = fb
                if fb.current_pose is not None:
                    self.tracker.feedback_pose(fb.current_pose)

    def _on_result(self, rec: RemoteGoal, fut: Future) -> None:
        if fut.exception() is not None:
            with self._lock:
                rec.finish(
                    GoalStatus.ABORTED, ErrorCode.SERVER_UNAVAILABLE, f"result lost: {fut.exception()}"
                )
            return
        res = fut.result()
        status = STATUS_MAP.get(res.status, GoalStatus.ABORTED)
        result = res.result
        code = int(getattr(result, "error_code", 0))
        msg = str(getattr(result, "error_msg", ""))
        with self._lock:
            if rec.kind == "follow_waypoints":
                rec.missed = tuple(int(m.index) for m in result.missed_waypoints)
            rec.path = result_path(rec.kind, result)
            if status is GoalStatus.CANCELED and not rec.cancel_wanted:
                status = GoalStatus.ABORTED  # canceled by someone else: not what we asked for
                msg = msg or "canceled by another client"
            rec.finish(status, code, msg)

    def _cancel_remote(self, rec: RemoteGoal) -> None:
        handle = rec.handle
        if handle is None:
            with self._lock:
                # never sent (server missing): cancel locally
                if rec.cancel_wanted:
                    rec.finish(GoalStatus.CANCELED, 0, "")
            return
        if isinstance(handle, ClientGoalHandle):
            self._owner.track_cancel(handle.cancel_goal_async())
        # else the request is in flight: _on_goal_response cancels it once accepted

    def _watchdog(self, now: float) -> None:
        """Send goals that waited for their server; end goals whose server vanished or never
        answered (executor thread)."""
        self.lifecycle.poll(now)
        with self._lock:
            for gid in [g for g, r in self._live.items() if r.status.terminal]:
                del self._live[gid]
            live = list(self._live.values())
        for rec in live:
            ready = self._ready(rec.kind)
            if rec.handle is None and ready:
                self._send_remote(rec)
                continue
            with self._lock:
                if ready:
                    rec.unavailable_since = None
                    if isinstance(rec.handle, Future) and now - rec.sent_at > self._timeout:
                        rec.finish(
                            GoalStatus.ABORTED,
                            ErrorCode.SERVER_UNAVAILABLE,
                            f"{self._ns}/{rec.kind} did not answer the goal request within {self._timeout:.1f} s",
                        )
                    continue
                if rec.unavailable_since is None:
                    rec.unavailable_since = now
                elif now - rec.unavailable_since >= self._timeout:
                    rec.finish(
                        GoalStatus.ABORTED,
                        ErrorCode.SERVER_UNAVAILABLE,
                        f"Nav2 action server {self._ns}/{rec.kind} is unavailable "
                        f"(not discovered for {self._timeout:.1f} s)",
                    )

    def _destroy(self) -> None:
        for c in self._clients.values():
            c.destroy()
        for s in self._services.values():
            self.node.destroy_client(s)
        self.lifecycle.destroy(self.node)
        self.node.destroy_node()


class RosBackends:
    """The backends of several namespaced Nav2 robots sharing one rclpy context and one
    executor thread. Use as a context manager or call :meth:`close` (idempotent)."""

    def __init__(
        self,
        namespaces: Iterable[str],
        *,
        domain_id: int | None = None,
        context: Context | None = None,
        server_timeout_s: float = 3.0,
        eager: Iterable[str] = BACKEND_KINDS,
    ) -> None:
        #: The action clients each robot makes at once (the others on first use).
        self.eager = tuple(eager)
        self.lock = threading.RLock()
        self._owns_context = context is None
        if context is None:
            context = Context()
            rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.context = context
        self._queue: deque[Callable[[], None]] = deque()
        self._closed = False
        #: Latest header stamp (s) seen on amcl_pose / odom: the robots' time (simulated time
        #: with ``fleet sim-ros``, ROS time with a real Nav2).
        self.latest_stamp = 0.0
        namespaces = list(namespaces)
        #: Each robot's newest odometry stamp (s), by the order of ``namespaces``.
        self._odom_t = np.zeros(len(namespaces))
        self._cancels: set[Future] = set()
        self._fleet_t = 0.0
        self._ready_at = 0.0
        self.backends: dict[str, RosNavigationBackend] = {}
        try:
            for ns in namespaces:
                ns = ns if ns.startswith("/") else "/" + ns
                if ns in self.backends:
                    raise BackendError(f"namespace {ns!r} listed twice")
                self.backends[ns] = RosNavigationBackend(self, ns, server_timeout_s, len(self.backends))
            self._helper = Node(
                "fleet_backends", context=context, start_parameter_services=False, enable_rosout=False
            )
            self._guard = self._helper.create_guard_condition(self._drain)
            self._helper.create_timer(0.1, self._tick)
            self.executor = SingleThreadedExecutor(context=context)
            self.executor.add_node(self._helper)
            for b in self.backends.values():
                self.executor.add_node(b.node)
        except Exception:
            if self._owns_context and context.ok():
                rclpy.shutdown(context=context)
            raise
        self._thread = threading.Thread(target=self._spin, name="fleet-ros-backends", daemon=True)
        self._thread.start()

    def __getitem__(self, namespace: str) -> RosNavigationBackend:
        return self.backends[namespace]

    def call_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the executor thread (thread-safe)."""
        self._queue.append(fn)
        if not self._closed:
            self._guard.trigger()

    def wait_for_servers(self, timeout_s: float = 30.0, kinds: Iterable[str] = BACKEND_KINDS) -> list[str]:
        """Wait until every robot's action servers ``kinds`` are discovered (read from the graph
        node by node: :mod:`fleet.ros.action_graph`); return those missing after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        want = frozenset(kinds)
        missing = list(self.backends)
        while True:  # looks at least once, also with timeout_s 0
            served = served_actions(self._helper, missing, OWN_NODES)
            missing = [ns for ns in missing if not want <= served[ns]]
            if not missing or time.monotonic() >= deadline:
                return missing
            time.sleep(0.1)

    def wait_until_active(self, timeout_s: float = 30.0, *, startup: bool = True) -> list[str]:
        """Wait until every robot's navigator (``bt_navigator``) is active, as
        ``BasicNavigator.waitUntilNav2Active`` does; with ``startup``, a robot whose nodes are
        unconfigured or inactive (Nav2 launched without ``autostart``) is brought up with a
        STARTUP to its lifecycle managers, as ``BasicNavigator.lifecycleStartup`` does.
        Returns the namespaces still not active after ``timeout_s`` (empty when all are)."""
        deadline = time.monotonic() + timeout_s
        missing = list(self.backends)
        while missing and time.monotonic() < deadline:
            for ns in missing:
                w = self.backends[ns].lifecycle
                if startup and not w.startup_sent and w.state in ("unconfigured", "inactive"):
                    self.call_soon(w.startup)
            time.sleep(0.05)
            missing = [ns for ns in missing if not self.backends[ns].lifecycle.active]
        return missing

    def fleet_time(self) -> float:
        """The fleet's clock (s of the robots' time): the newest odometry stamp *every* robot
        has reached, so that each robot's pose read at this time is the pose of this time
        (taking the newest stamp of any robot instead would read the others' poses from
        before it: the time-matching of :mod:`fleet.ros.frames`, across robots). A robot whose
        odometry is more than :data:`CLOCK_LAG_S` behind the newest stamp (its Nav2 is gone)
        does not hold the clock back; the clock never goes back."""
        newest = self.latest_stamp
        ts = self._odom_t
        recent = ts[ts >= newest - CLOCK_LAG_S]
        t = float(recent.min()) if recent.size else newest
        if t > self._fleet_t:
            self._fleet_t = t
        return self._fleet_t

    def saw_odom(self, index: int, t: float) -> None:
        """Record robot ``index``'s newest odometry stamp ``t`` (s; executor thread)."""
        if t > self._odom_t[index]:
            self._odom_t[index] = t

    def saw_stamp(self, stamp: Time) -> None:
        """Record a header stamp seen on a robot's topic (executor thread)."""
        t = float(stamp.sec) + float(stamp.nanosec) * 1e-9
        if t > self.latest_stamp:
            self.latest_stamp = t

    def _drain(self) -> None:
        while self._queue:
            fn = self._queue.popleft()
            fn()

    def _tick(self) -> None:
        self._drain()
        now = time.monotonic()
        for b in self.backends.values():
            b._watchdog(now)
        # servers discovered: the whole fleet every READY_PERIOD_S, else the robots wanting it
        if now >= self._ready_at:
            self._ready_at, ask = now + READY_PERIOD_S, list(self.backends)
        else:
            ask = [ns for ns, b in self.backends.items() if b._sweep_wanted()]
        served = served_actions(self._helper, ask, OWN_NODES) if ask else {}
        for ns in ask:
            b = self.backends[ns]
            b.served = served[ns]
            b.servers_ready = b.lifecycle.active and b._clients.keys() | set(BACKEND_KINDS) <= b.served

    def _spin(self) -> None:
        while not self._closed and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001 - a shut-down context ends the loop
                if self._closed or not self.context.ok():
                    break
                raise

    def track_cancel(self, fut: Future) -> None:
        """Remember a cancel request until it is answered (:meth:`close` waits for it)."""
        self._cancels.add(fut)
        fut.add_done_callback(self._cancels.discard)

    def close(self) -> None:
        """Send what is queued (the cancels of goals the agents canceled as they closed: a
        robot must not drive on after the run) and wait up to :data:`CLOSE_FLUSH_S` for their
        answers; then stop the executor thread, destroy the nodes, shut the context down."""
        if self._closed:
            return
        deadline = time.monotonic() + CLOSE_FLUSH_S
        self._guard.trigger()
        while (self._queue or self._cancels) and time.monotonic() < deadline and self._thread.is_alive():
            time.sleep(0.01)
        self._closed = True
        self._thread.join(timeout=5.0)
        for b in self.backends.values():
            b._destroy()
        self._helper.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        if self._owns_context and self.context.ok():
            rclpy.shutdown(context=self.context)

    def __enter__(self) -> RosBackends:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_ros_backends(
    namespaces: Iterable[str],
    *,
    domain_id: int | None = None,
    context: Context | None = None,
    server_timeout_s: float = 3.0,
    wait_s: float | None = None,
    startup: bool = True,
    eager: Iterable[str] = BACKEND_KINDS,
) -> RosBackends:
    """Create ROS backends for ``namespaces`` (e.g. ``["/robot1", "/robot2"]``).

    Returns a :class:`RosBackends`: ``.backends[ns]`` is each robot's
    :class:`RosNavigationBackend`; ``.close()`` stops the shared executor thread and the
    context. With ``wait_s``, waits that long for every robot's Nav2 action servers, then that
    long again for every robot's navigator to be active (sending its lifecycle managers
    STARTUP when its nodes are unconfigured, unless ``startup`` is false: see
    :meth:`RosBackends.wait_until_active`), and raises :class:`~fleet.errors.BackendError`
    naming the robots still missing. ``eager``: the action clients made at once (fewer, e.g.
    the two navigators, cut discovery work at scale; the others are made on first use).
    """
    rb = RosBackends(namespaces, domain_id=domain_id, context=context, server_timeout_s=server_timeout_s, eager=eager)  # fmt: skip
    if wait_s is not None:
        missing = rb.wait_for_servers(wait_s)
        if missing:
            rb.close()
            raise BackendError(
                f"no Nav2 action servers found within {wait_s:.0f} s for {', '.join(missing)} "
                f"(ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}; is `fleet sim-ros` running?)"
            )
        missing = rb.wait_until_active(wait_s, startup=startup)
        if missing:
            states = ", ".join(f"{ns} ({rb.backends[ns].lifecycle.state})" for ns in missing)
            rb.close()
            raise BackendError(
                f"Nav2 not active within {wait_s:.0f} s on {states}: bt_navigator/get_state is not "
                "'active'" + ("" if startup else " (bring it up with its lifecycle managers' STARTUP)")
            )
    return rb


__all__ = ["RosBackends", "RosNavigationBackend", "make_ros_backends"]
