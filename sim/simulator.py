"""The kinematic multi-robot simulator: a fixed-step world of differential-drive robots that
stands in for a fleet of Nav2 robots.

One :class:`Simulator` owns the robots, the static map (an
:class:`~sim.occupancy.OccupancyGrid`), dynamic round obstacles and every goal ever sent. Time
is the :class:`~fleet.clock.SimClock` passed in; :meth:`Simulator.step` advances it by
``params.step_s`` and moves every robot; nothing reads the wall clock and nothing is random,
so the same inputs give the same run.

Each step, for every robot in insertion order:

1. its executing goal (a :class:`sim.robot.Task`) proposes a command ``(v, w)``;
2. acceleration limits of :class:`~sim.params.RobotModel` are applied;
3. the reactive safety layer limits ``v`` so the robot can stop
   :data:`STOP_GAP_M` before another robot or dynamic obstacle in the corridor ahead in its
   direction of travel (what Nav2's local costmap / collision monitor do);
4. a stalled robot or an empty battery does not move; motion that would put the robot's
   footprint on a static obstacle (or off the map) or into a dynamic obstacle is refused;
5. odometer, battery (drain or charge) and the stuck detector are updated.

Then robot-robot contacts (center distance < 2 * radius) are counted: a pair that starts
touching is one collision event.

Goals are addressed by ids ``"<namespace>#<n>"``, never reused. See ``docs/simulator.md``
for the action semantics and error codes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from fleet.clock import SimClock
from fleet.errors import BackendError
from fleet.types import (
    BackUp,
    DriveOnHeading,
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
from sim.occupancy import OccupancyGrid
from sim.params import RobotSpec, SimParams
from sim.planner import GridPlanner
from sim.robot import (
    DriveTask,
    FollowWaypointsTask,
    GoalRecord,
    NavigateTask,
    Robot,
    SpinTask,
    Task,
    WaitTask,
)

if TYPE_CHECKING:
    from sim.backend import SimNavigationBackend

#: The reactive layer stops a robot this far (m) from the robot or obstacle ahead.
STOP_GAP_M = 0.1
#: Extra half-width (m) of the corridor ahead that the reactive layer watches.
CORRIDOR_MARGIN_M = 0.05
#: A robot that moved this far (m) from where it last made progress has made progress.
PROGRESS_RADIUS_M = 0.1
#: Trajectories are sampled every this many simulated seconds.
TRAJECTORY_PERIOD_S = 0.5
#: Fault names accepted by :meth:`Simulator.set_fault`.
FAULTS = ("stalled",)


class Simulator:
    """A fixed-step kinematic simulator of round differential-drive robots on a static map.

    Args:
        grid: the static map (``map`` frame, meters). Non-free cells are obstacles.
        params: step, tolerances, stuck time, chargers, robot and battery models.
        clock: the simulated clock; :meth:`step` advances it. Pass a fresh ``SimClock()``
            unless several components must share one clock.
    """

    def __init__(self, grid: OccupancyGrid, params: SimParams, clock: SimClock) -> None:
        if params.step_s <= 0:
            raise BackendError(f"SimParams.step_s must be positive, got {params.step_s}")
        self.grid = grid
        self.params = params
        self.clock = clock
        self.planner = GridPlanner(grid, params.model.radius)
        self._robots: dict[str, Robot] = {}
        self._order: list[Robot] = []
        self._goals: dict[str, GoalRecord] = {}
        self._goal_counter: dict[str, int] = {}
        self._obstacles: dict[int, tuple[float, float, float]] = {}
        self._next_obstacle = 1
        self._touching: set[tuple[str, str]] = set()
        self._next_sample = clock.now() + TRAJECTORY_PERIOD_S
        self._backends: dict[str, SimNavigationBackend] = {}
        self.collisions = 0
        self.collision_events: list[tuple[float, str, str, float, float]] = []
        self.steps = 0

    # -- robots -----------------------------------------------------------------------

    @property
    def namespaces(self) -> list[str]:
        """Robot namespaces in the order they were added."""
        return [r.namespace for r in self._order]

    def add_robot(self, spec: RobotSpec) -> None:
        """Add a robot at ``spec.start``. Raises :class:`BackendError` if the namespace is
        taken or the robot's footprint at the start overlaps a static obstacle or leaves the
        map. Robots may be placed touching each other (that counts as a collision event at the
        next step)."""
        ns = spec.namespace
        if ns in self._robots:
            raise BackendError(f"robot namespace {ns!r} is already in the simulator")
        p = spec.start
        if not (math.isfinite(p.x) and math.isfinite(p.y) and math.isfinite(p.theta)):
            raise BackendError(f"robot {ns}: start pose {p} is not finite")
        if not self.planner.footprint_free(p.x, p.y):
            raise BackendError(
                f"robot {ns}: start pose ({p.x:.2f}, {p.y:.2f}) is not free for a robot of radius "
                f"{self.params.model.radius} m (obstacle or outside the map {self.grid.source})"
            )
        robot = Robot(spec.name, ns, p, spec.battery, self.clock.now())
        self._robots[ns] = robot
        self._order.append(robot)
        self._goal_counter[ns] = 0

    def _robot(self, namespace: str) -> Robot:
        try:
            return self._robots[namespace]
        except KeyError:
            raise BackendError(f"no robot with namespace {namespace!r} in the simulator") from None

    def robot_state(self, namespace: str) -> RobotState:
        """Current state of the robot ``namespace`` (pose always known in the sim)."""
        r = self._robot(namespace)
        return RobotState(
            pose=Pose2D(r.x, r.y, r.theta),
            linear_velocity=r.v,
            angular_velocity=r.w,
            battery=r.battery,
            charging=r.charging,
            stuck=r.stuck,
            distance_m=r.distance_m,
            collisions=r.collisions,
        )

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]]:
        """``(t, x, y)`` samples of the robot, one at its addition and then every
        :data:`TRAJECTORY_PERIOD_S` simulated seconds (a copy)."""
        return list(self._robot(namespace).trajectory)

    def set_fault(self, namespace: str, fault: str | None) -> None:
        """Inject a fault: ``"stalled"`` makes the wheels stop responding (the robot stops at
        once and cannot move or turn); ``None`` clears it."""
        if fault is not None and fault not in FAULTS:
            raise BackendError(f"unknown fault {fault!r}; known faults: {', '.join(FAULTS)}")
        self._robot(namespace).fault = fault

    def backend(self, namespace: str) -> SimNavigationBackend:
        """A :class:`~fleet.navigation.NavigationBackend` for robot ``namespace``."""
        from sim.backend import SimNavigationBackend

        self._robot(namespace)
        b = self._backends.get(namespace)
        if b is None:
            b = SimNavigationBackend(self, namespace)
            self._backends[namespace] = b
        return b

    # -- obstacles --------------------------------------------------------------------

    def add_obstacle(self, x: float, y: float, radius: float) -> int:
        """Add a dynamic round obstacle (not in global plans; robots stop before it and cannot
        enter it). Returns its id."""
        if radius <= 0:
            raise BackendError(f"obstacle radius must be positive, got {radius}")
        oid = self._next_obstacle
        self._next_obstacle += 1
        self._obstacles[oid] = (float(x), float(y), float(radius))
        return oid

    def remove_obstacle(self, obstacle_id: int) -> None:
        """Remove a dynamic obstacle; unknown ids are ignored."""
        self._obstacles.pop(obstacle_id, None)

    # -- goals ------------------------------------------------------------------------

    def send_goal(self, namespace: str, goal: Goal) -> str:
        """Start ``goal`` on robot ``namespace`` and return its fresh id at once.

        The goal is EXECUTING immediately, or already terminal if it was REJECTED (a
        NavigateThroughPoses without poses, a non-finite pose) or ABORTED at start (planning
        failure, invalid BackUp input, ...). A goal the robot was executing ends ABORTED with
        an error message naming the preempting goal.
        """
        robot = self._robot(namespace)
        self._goal_counter[namespace] += 1
        gid = f"{namespace}#{self._goal_counter[namespace]}"
        record = GoalRecord(gid, goal, namespace)
        self._goals[gid] = record
        old = robot.task
        if old is not None and not old.done:
            old.record.feedback = old.feedback()
            old.record.finish(
                GoalStatus.ABORTED, 0, f"Goal {old.record.goal_id} was preempted by goal {gid}."
            )
        robot.task = None
        now = self.clock.now()
        reject = _reject_reason(goal)
        if reject is not None:
            record.finish(GoalStatus.REJECTED, 0, reject)
            return gid
        task: Task
        if isinstance(goal, NavigateToPose):
            task = NavigateTask(record, robot, self, now, (goal.pose,))
        elif isinstance(goal, NavigateThroughPoses):
            task = NavigateTask(record, robot, self, now, tuple(goal.poses))
        elif isinstance(goal, FollowWaypoints):
            task = FollowWaypointsTask(record, robot, self, now, tuple(goal.poses))
        elif isinstance(goal, Spin):
            task = SpinTask(record, robot, self, now, goal.target_yaw, goal.time_allowance_s)
        elif isinstance(goal, BackUp):
            task = DriveTask(
                record, robot, self, now, -1.0, goal.distance_m, goal.speed_mps, goal.time_allowance_s
            )
        elif isinstance(goal, DriveOnHeading):
            task = DriveTask(
                record, robot, self, now, 1.0, goal.distance_m, goal.speed_mps, goal.time_allowance_s
            )
        else:
            assert isinstance(goal, Wait)
            task = WaitTask(record, robot, self, now, goal.duration_s)
        if not task.done:
            robot.task = task
            robot.progress_x, robot.progress_y, robot.progress_t = robot.x, robot.y, now
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        """Snapshot of goal ``goal_id`` (pure read). Raises ``KeyError`` for an id never issued."""
        record = self._goals[goal_id]
        if not record.status.terminal:
            task = self._robots[record.namespace].task
            if task is not None and task.record is record:
                return record.snapshot(task.feedback())
        return record.snapshot()

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id``: it ends CANCELED at once and the robot decelerates to a stop.
        A no-op for a finished or unknown goal."""
        record = self._goals.get(goal_id)
        if record is None or record.status.terminal:
            return
        robot = self._robots[record.namespace]
        task = robot.task
        if task is not None and task.record is record:
            record.feedback = task.feedback()
            robot.task = None
        record.finish(GoalStatus.CANCELED, 0, "")

    # -- stepping ---------------------------------------------------------------------

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Step until ``predicate()`` is true (checked before each step) or ``timeout_s``
        simulated seconds have passed. Returns whether the predicate became true."""
        end = self.clock.now() + timeout_s - 1e-9
        while True:
            if predicate():
                return True
            if self.clock.now() >= end:
                return False
            self.step()

    def step(self) -> None:
        """Advance the clock by ``params.step_s`` and move every robot (see module docstring)."""
        p = self.params
        dt = p.step_s
        now = self.clock.advance(dt)
        self.steps += 1
        for robot in self._order:
            self._step_robot(robot, now, dt)
        self._count_contacts(now)
        if now >= self._next_sample - 1e-9:
            for robot in self._order:
                robot.trajectory.append((now, robot.x, robot.y))
            while self._next_sample <= now + 1e-9:
                self._next_sample += TRAJECTORY_PERIOD_S

    def _step_robot(self, robot: Robot, now: float, dt: float) -> None:
        p = self.params
        m = p.model
        task = robot.task
        v_des = w_des = 0.0
        if task is not None:
            v_des, w_des = task.control(now, dt)
            if task.done:
                robot.task = task = None
        # acceleration limits
        dv = m.max_linear_accel * dt
        dw = m.max_angular_accel * dt
        v = min(max(v_des, robot.v - dv), robot.v + dv)
        w = min(max(w_des, robot.w - dw), robot.w + dw)
        v = min(max(v, -m.max_linear_speed), m.max_linear_speed)
        w = min(max(w, -m.max_angular_speed), m.max_angular_speed)
        if robot.fault == "stalled" or robot.battery <= 0.0:
            v = w = 0.0
        # reactive safety layer: be able to stop STOP_GAP_M before whatever is ahead
        if v != 0.0:
            direction = 1.0 if v > 0 else -1.0
            look = v * v / (2.0 * m.max_linear_accel) + STOP_GAP_M + abs(v) * dt + 0.05
            free = self.free_distance(robot, direction, look, False)
            if free < look:
                vmax = math.sqrt(2.0 * m.max_linear_accel * max(free - STOP_GAP_M, 0.0))
                vmax = min(vmax, max(free - STOP_GAP_M, 0.0) / dt)
                if abs(v) > vmax:
                    v = direction * vmax
        # integrate
        th = robot.theta
        ds = v * dt
        dth = w * dt
        moved = False
        if ds != 0.0:
            mid = th + 0.5 * dth
            nx = robot.x + ds * math.cos(mid)
            ny = robot.y + ds * math.sin(mid)
            ok = self.planner.footprint_free(nx, ny) and not self._enters_obstacle(robot, nx, ny)
            if not ok:
                # slide along the obstacle: keep the larger free axis-aligned part of the move
                ex, ey = nx - robot.x, ny - robot.y
                cand = (robot.x + ex, robot.y) if abs(ex) >= abs(ey) else (robot.x, robot.y + ey)
                alt = (robot.x, robot.y + ey) if abs(ex) >= abs(ey) else (robot.x + ex, robot.y)
                for cx, cy in (cand, alt):
                    if (
                        (cx, cy) != (robot.x, robot.y)
                        and self.planner.footprint_free(cx, cy)
                        and not self._enters_obstacle(robot, cx, cy)
                    ):
                        nx, ny, ok = cx, cy, True
                        break
            if ok:
                ex, ey = nx - robot.x, ny - robot.y
                step_len = math.hypot(ex, ey)
                ds = math.copysign(step_len, ds)
                v = ds / dt
                robot.x, robot.y = nx, ny
                moved = True
            else:
                ds = 0.0
                v = 0.0
        robot.theta = (th + dth + math.pi) % (2.0 * math.pi) - math.pi
        robot.v, robot.w = v, w
        dist = abs(ds)
        robot.distance_m += dist
        if task is not None:
            task.after_move(ds, dth)
        # battery
        b = p.battery
        charging = False
        if not moved and w == 0.0 and p.chargers:
            for c in p.chargers:
                if math.hypot(c.x - robot.x, c.y - robot.y) <= p.charger_radius:
                    charging = True
                    break
        if charging:
            robot.battery = min(1.0, robot.battery + b.charge_per_s * dt)
        else:
            robot.battery = max(0.0, robot.battery - b.drain_per_m * dist - b.drain_per_s * dt)
        robot.charging = charging
        # stuck detector (progress checker)
        if math.hypot(robot.x - robot.progress_x, robot.y - robot.progress_y) > PROGRESS_RADIUS_M:
            robot.progress_x, robot.progress_y, robot.progress_t = robot.x, robot.y, now
            robot.stuck = False
        elif task is None or not task.drives:
            robot.progress_t = now
        elif now - robot.progress_t >= p.stuck_time_s - 1e-9:
            robot.stuck = True
            robot.progress_t = now
            task.on_stuck()
            if task.done:
                robot.task = None

    def _enters_obstacle(self, robot: Robot, nx: float, ny: float) -> bool:
        if not self._obstacles:
            return False
        r = self.params.model.radius
        for ox, oy, orad in self._obstacles.values():
            lim = r + orad
            d_new = math.hypot(nx - ox, ny - oy)
            if d_new < lim and d_new < math.hypot(robot.x - ox, robot.y - oy):
                return True
        return False

    def free_distance(
        self, robot: Robot, direction: float, lookahead: float, static: bool, heading: float | None = None
    ) -> float:
        """Distance (m) the center of ``robot`` can travel straight along ``heading`` (default:
        its current yaw; ``direction`` +1 forward, -1 backward) before its footprint touches
        another robot or a dynamic obstacle (and, if ``static``, a static obstacle or the map
        edge), capped at ``lookahead``. Only things in the corridor of the robot's width ahead
        count."""
        r = self.params.model.radius
        yaw = robot.theta if heading is None else heading
        hx = math.cos(yaw) * direction
        hy = math.sin(yaw) * direction
        x, y = robot.x, robot.y
        best = lookahead
        reach = lookahead + 2.0 * r + 1.0
        for other in self._order:
            if other is robot:
                continue
            dx = other.x - x
            dy = other.y - y
            if abs(dx) > reach or abs(dy) > reach:
                continue
            best = min(best, _corridor_gap(dx, dy, hx, hy, 2.0 * r, best))
        for ox, oy, orad in self._obstacles.values():
            best = min(best, _corridor_gap(ox - x, oy - y, hx, hy, r + orad, best))
        if static and best > 0.0:
            stepd = 0.5 * self.grid.resolution
            s = stepd
            while s <= best:
                if not self.planner.footprint_free(x + hx * s, y + hy * s):
                    best = max(0.0, s - stepd)
                    break
                s += stepd
        return best

    def _count_contacts(self, now: float) -> None:
        robots = sorted(self._order, key=lambda rb: rb.x)
        d2 = 2.0 * self.params.model.radius
        touching: set[tuple[str, str]] = set()
        n = len(robots)
        for i in range(n):
            a = robots[i]
            for j in range(i + 1, n):
                b = robots[j]
                if b.x - a.x >= d2:
                    break
                if math.hypot(b.x - a.x, b.y - a.y) < d2:
                    pair = (
                        (a.namespace, b.namespace)
                        if a.namespace < b.namespace
                        else (b.namespace, a.namespace)
                    )
                    touching.add(pair)
        for pair in sorted(touching - self._touching):
            ra, rb = self._robots[pair[0]], self._robots[pair[1]]
            ra.collisions += 1
            rb.collisions += 1
            self.collisions += 1
            self.collision_events.append((now, pair[0], pair[1], 0.5 * (ra.x + rb.x), 0.5 * (ra.y + rb.y)))
        self._touching = touching


def _corridor_gap(dx: float, dy: float, hx: float, hy: float, contact: float, cap: float) -> float:
    """How far along unit heading ``(hx, hy)`` a disc can move before its center comes within
    ``contact`` of a point at offset ``(dx, dy)``; ``cap`` if the point is not ahead in the
    corridor. Returns 0 if already in contact and the point is ahead."""
    along = dx * hx + dy * hy
    if along <= 0.0:
        return cap
    lateral = abs(dx * hy - dy * hx)
    if lateral >= contact + CORRIDOR_MARGIN_M:
        return cap
    if lateral >= contact:
        return max(0.0, along - contact)
    return max(0.0, along - math.sqrt(contact * contact - lateral * lateral))


def _reject_reason(goal: Goal) -> str | None:
    if isinstance(goal, NavigateThroughPoses) and not goal.poses:
        return "NavigateThroughPoses needs at least one pose."
    poses: tuple[Pose2D, ...] = ()
    if isinstance(goal, NavigateToPose):
        poses = (goal.pose,)
    elif isinstance(goal, (NavigateThroughPoses, FollowWaypoints)):
        poses = tuple(goal.poses)
    elif not isinstance(goal, (Spin, BackUp, DriveOnHeading, Wait)):
        raise BackendError(f"unsupported goal type {type(goal).__name__}")
    for i, pose in enumerate(poses):
        if not (math.isfinite(pose.x) and math.isfinite(pose.y) and math.isfinite(pose.theta)):
            return f"Pose {i} ({pose.x}, {pose.y}, {pose.theta}) is not finite."
    return None
