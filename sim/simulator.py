"""The kinematic multi-robot simulator: a fixed-step world of differential-drive robots that
stands in for a fleet of Nav2 robots.

One :class:`Simulator` owns the robots, the static map (an
:class:`~sim.occupancy.OccupancyGrid`), dynamic round obstacles and every goal ever sent. Time
is the :class:`~fleet.clock.SimClock` passed in; :meth:`Simulator.step` advances it by
``params.step_s`` and moves every robot; nothing reads the wall clock and nothing is random,
so the same inputs give the same run.

Each step moves all robots together; the state lives in NumPy arrays
(:class:`sim.state.FleetState`) and every stage below is an array operation over all robots:

1. commands: goals that are not path following (Spin, BackUp, DriveOnHeading, Wait,
   FollowWaypoints between waypoints) run their Python :class:`sim.robot.Task` in insertion
   order; every robot following a path gets its ``(v, w)`` from the vectorized follower
   (:meth:`Simulator._follow`: progress along the path, passed poses, lookahead target, detour
   around robots and dynamic obstacles, turn-then-drive). Tasks hear about arrivals, missing
   approach and stuck robots as events, never per step;
2. acceleration limits of :class:`~sim.params.RobotModel` are applied;
3. the reactive safety layer limits ``v`` so the robot can stop :data:`STOP_GAP_M` before
   another robot or dynamic obstacle in the corridor ahead in its direction of travel (what
   Nav2's local costmap / collision monitor do);
4. a stalled robot or an empty battery does not move; motion that would put the robot's
   footprint on a static obstacle (or off the map) or into a dynamic obstacle is refused
   (sliding along it when one axis of the move is free);
5. odometer, battery (drain or charge) and the stuck detector are updated.

Then robot-robot contacts (center distance < 2 * radius) are counted: a pair that starts
touching is one collision event. Robot pairs that can matter (closer than about 2.2 m) come
from a uniform-grid spatial hash (:func:`sim.spatial.neighbor_pairs`), and robots see each
other where they were at the start of the step.

Goals are addressed by ids ``"<namespace>#<n>"``, never reused. See ``docs/simulator.md``
for the action semantics and error codes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from fleet.clock import SimClock
from fleet.errors import BackendError
from fleet.navigation import Clock
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
    normalize_angle,
)
from sim.occupancy import OccupancyGrid
from sim.params import RobotSpec, SimParams
from sim.planner import GridPlanner
from sim.robot import (
    APPROACH_FACTOR,
    APPROACH_M,
    AVOID_CLEAR_M,
    AVOID_LOOKAHEAD_M,
    AVOID_OFFSETS,
    HEADING_GAIN,
    ROTATE_IN_PLACE_RAD,
    DriveTask,
    FollowWaypointsTask,
    GoalRecord,
    NavigateTask,
    Robot,
    SpinTask,
    Task,
    WaitTask,
)
from sim.spatial import neighbor_pairs
from sim.state import FleetState

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
#: The neighbor-pair list is rebuilt every this many steps (with a margin for the motion
#: in between), not every step.
PAIR_REUSE_STEPS = 4
#: Fault names accepted by :meth:`Simulator.set_fault`.
FAULTS = ("stalled",)


def step_until(
    clock: Clock, step: Callable[[], None], predicate: Callable[[], bool], timeout_s: float
) -> bool:
    """Call ``step()`` until ``predicate()`` is true (checked before each step) or ``clock``
    has advanced ``timeout_s`` seconds. Returns whether the predicate became true. Shared by
    every stepped world (the simulator, SUMO)."""
    end = clock.now() + timeout_s - 1e-9
    while True:
        if predicate():
            return True
        if clock.now() >= end:
            return False
        step()


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
        self.state = FleetState()
        self._robots: dict[str, Robot] = {}
        self._order: list[Robot] = []
        self._py: dict[int, Robot] = {}
        self._goals: dict[str, GoalRecord] = {}
        self._goal_counter: dict[str, int] = {}
        self._obstacles: dict[int, tuple[float, float, float]] = {}
        self._next_obstacle = 1
        self._touching: set[tuple[int, int]] = set()
        self._next_sample = clock.now() + TRAJECTORY_PERIOD_S
        self._samples_t: list[float] = []
        self._samples_xy: list[np.ndarray] = []
        self._traj_start: list[tuple[float, float, float, int]] = []
        self._backends: dict[str, SimNavigationBackend] = {}
        self._fp_flat = self.planner.footprint.ravel()
        self._chargers = np.array([(c.x, c.y) for c in params.chargers], dtype=float).reshape(-1, 2)
        m = params.model
        vmax = m.max_linear_speed
        look_max = vmax * vmax / (2.0 * m.max_linear_accel) + STOP_GAP_M + vmax * params.step_s + 0.05
        reach = max(AVOID_LOOKAHEAD_M, AVOID_CLEAR_M, look_max) + 2.0 * m.radius
        #: pairs closer than this can matter to the avoidance and safety checks
        self._pair_radius = math.hypot(reach, 2.0 * m.radius + CORRIDOR_MARGIN_M) + 0.01
        samples: list[float] = []
        stepd = 0.5 * grid.resolution
        sd = stepd
        while sd <= AVOID_CLEAR_M:
            samples.append(sd)
            sd += stepd
        self._clear_samples = np.array(samples)
        self._pi = np.zeros(0, dtype=np.int64)
        self._pj = np.zeros(0, dtype=np.int64)
        self._pairs_n = -1
        self._pairs_step = 0
        self._pdx = np.zeros(0)
        self._pdy = np.zeros(0)
        self._pd2 = np.zeros(0)
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
        now = self.clock.now()
        battery = min(1.0, max(0.0, float(spec.battery)))
        i = self.state.add(float(p.x), float(p.y), normalize_angle(float(p.theta)), battery, now)
        robot = Robot(spec.name, ns, i, self.state)
        self._robots[ns] = robot
        self._order.append(robot)
        self._goal_counter[ns] = 0
        self._traj_start.append((now, float(p.x), float(p.y), len(self._samples_t)))

    def _robot(self, namespace: str) -> Robot:
        try:
            return self._robots[namespace]
        except KeyError:
            raise BackendError(f"no robot with namespace {namespace!r} in the simulator") from None

    def robot_state(self, namespace: str) -> RobotState:
        """Current state of the robot ``namespace`` (pose always known in the sim)."""
        r = self._robot(namespace)
        s, i = self.state, r.index
        return RobotState(
            pose=Pose2D(float(s.x[i]), float(s.y[i]), float(s.th[i])),
            linear_velocity=float(s.v[i]),
            angular_velocity=float(s.w[i]),
            battery=float(s.battery[i]),
            charging=bool(s.charging[i]),
            stuck=bool(s.stuck[i]),
            distance_m=float(s.dist[i]),
            collisions=int(s.collisions[i]),
        )

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]]:
        """``(t, x, y)`` samples of the robot, one at its addition and then every
        :data:`TRAJECTORY_PERIOD_S` simulated seconds (a copy)."""
        i = self._robot(namespace).index
        t0, x0, y0, first = self._traj_start[i]
        out = [(t0, x0, y0)]
        for t, xy in zip(self._samples_t[first:], self._samples_xy[first:], strict=True):
            out.append((t, float(xy[i, 0]), float(xy[i, 1])))
        return out

    def set_fault(self, namespace: str, fault: str | None) -> None:
        """Inject a fault: ``"stalled"`` makes the wheels stop responding (the robot stops at
        once and cannot move or turn); ``None`` clears it."""
        if fault is not None and fault not in FAULTS:
            raise BackendError(f"unknown fault {fault!r}; known faults: {', '.join(FAULTS)}")
        r = self._robot(namespace)
        r.fault = fault
        self.state.stalled[r.index] = fault == "stalled"

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

    def _obstacle_array(self) -> np.ndarray:
        return np.array(list(self._obstacles.values()), dtype=float).reshape(-1, 3)

    # -- goals ------------------------------------------------------------------------

    def _set_task(self, robot: Robot, task: Task | None) -> None:
        i = robot.index
        robot.task = task
        self.state.fol[i] = False
        self.state.has_task[i] = task is not None
        self.state.drives[i] = False
        self._py.pop(i, None)
        if task is not None:
            if isinstance(task, NavigateTask):
                task.start(self.clock.now())
            if not self.state.fol[i]:
                self._py[i] = robot

    def _task_changed(self, robot: Robot) -> None:
        """Re-file a robot whose task ended, or started / stopped following a path."""
        task = robot.task
        i = robot.index
        if task is None or task.done:
            robot.task = None
            self.state.fol[i] = False
            self.state.has_task[i] = False
            self._py.pop(i, None)
        elif self.state.fol[i]:
            self._py.pop(i, None)
        else:
            self._py[i] = robot

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
        self._set_task(robot, None)
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
            self._set_task(robot, task)
            s, i = self.state, robot.index
            s.px[i], s.py[i], s.pt[i] = s.x[i], s.y[i], now
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
            self._set_task(robot, None)
        record.finish(GoalStatus.CANCELED, 0, "")

    # -- the World protocol of sim.robot ----------------------------------------------

    def attach_path(
        self, robot: Robot, path: list[tuple[float, float]], vias: list[int], final_yaw: float, now: float
    ) -> None:
        """Let the vectorized follower drive ``robot`` along ``path`` (see :class:`sim.robot.World`)."""
        self.state.attach(robot.index, path, vias, final_yaw, now)
        self._py.pop(robot.index, None)

    def detach_path(self, robot: Robot) -> None:
        """Stop following the robot's path; its task gets :meth:`Task.control` calls again."""
        self.state.detach(robot.index)
        if robot.task is not None and not robot.task.done:
            self._py[robot.index] = robot

    def path_remaining(self, robot: Robot) -> float:
        """Distance (m) along the followed path to its end (0 once the position is reached)."""
        return self.state.remaining(robot.index)

    def poses_remaining(self, robot: Robot) -> int:
        """Poses of the followed path not yet passed."""
        return self.state.poses_left(robot.index)

    # -- stepping ---------------------------------------------------------------------

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Step until ``predicate()`` is true (checked before each step) or ``timeout_s``
        simulated seconds have passed. Returns whether the predicate became true."""
        return step_until(self.clock, self.step, predicate, timeout_s)

    def step(self) -> None:
        """Advance the clock by ``params.step_s`` and move every robot (see module docstring)."""
        p = self.params
        dt = p.step_s
        now = self.clock.advance(dt)
        self.steps += 1
        s = self.state
        n = s.n
        if n == 0:
            return
        if n != self._pairs_n or self.steps - self._pairs_step >= PAIR_REUSE_STEPS:
            # a Verlet list: pairs within the radius plus what PAIR_REUSE_STEPS steps can close
            skin = 2.0 * p.model.max_linear_speed * dt * PAIR_REUSE_STEPS
            self._pi, self._pj = neighbor_pairs(s.x[:n], s.y[:n], self._pair_radius + skin)
            self._pairs_n, self._pairs_step = n, self.steps
        pi, pj = self._pi, self._pj
        self._pdx = s.x[pj] - s.x[pi]
        self._pdy = s.y[pj] - s.y[pi]
        self._pd2 = self._pdx * self._pdx + self._pdy * self._pdy
        obst = self._obstacle_array()
        vd = s.vd[:n]
        wd = s.wd[:n]
        vd[:] = 0.0
        wd[:] = 0.0
        # 1. commands: Python tasks (rare: Spin, BackUp, Wait, between waypoints) ...
        py_robots = [self._py[i] for i in sorted(self._py)]
        for robot in py_robots:
            task = robot.task
            assert task is not None
            i = robot.index
            vd[i], wd[i] = task.control(now, dt)
            s.drives[i] = task.drives
            self._task_changed(robot)
        # ... and the vectorized path follower for every robot driving along a path
        fol = np.flatnonzero(s.fol[:n])
        if fol.size:
            self._follow(fol, now, pi, pj, obst)
        # 2. acceleration and speed limits, faults
        m = p.model
        dv = m.max_linear_accel * dt
        dw = m.max_angular_accel * dt
        v0 = s.v[:n]
        w0 = s.w[:n]
        v = np.clip(np.minimum(np.maximum(vd, v0 - dv), v0 + dv), -m.max_linear_speed, m.max_linear_speed)
        w = np.clip(np.minimum(np.maximum(wd, w0 - dw), w0 + dw), -m.max_angular_speed, m.max_angular_speed)
        dead = s.stalled[:n] | (s.battery[:n] <= 0.0)
        v[dead] = 0.0
        w[dead] = 0.0
        x = s.x[:n]
        y = s.y[:n]
        th = s.th[:n]
        # 3. reactive safety layer: be able to stop STOP_GAP_M before whatever is ahead
        mv = np.flatnonzero(v != 0.0)
        if mv.size:
            vm = v[mv]
            direction = np.where(vm > 0, 1.0, -1.0)
            look = vm * vm / (2.0 * m.max_linear_accel) + STOP_GAP_M + np.abs(vm) * dt + 0.05
            hx = np.cos(th[mv]) * direction
            hy = np.sin(th[mv]) * direction
            free = self._free_dynamic(mv, hx, hy, look, pi, pj, obst, n)
            lim = free < look
            if lim.any():
                room = np.maximum(free - STOP_GAP_M, 0.0)
                vmax = np.minimum(np.sqrt(2.0 * m.max_linear_accel * room), room / dt)
                cut = lim & (np.abs(vm) > vmax)
                v[mv[cut]] = direction[cut] * vmax[cut]
        # 4. integrate, refusing moves into static or dynamic obstacles (sliding along them)
        ds = v * dt
        dth = w * dt
        moved = np.zeros(n, dtype=bool)
        mv = np.flatnonzero(ds != 0.0)
        if mv.size:
            mid = th[mv] + 0.5 * dth[mv]
            ox, oy = x[mv], y[mv]
            nx = ox + ds[mv] * np.cos(mid)
            ny = oy + ds[mv] * np.sin(mid)
            ok = self._footprint_free(nx, ny) & ~self._enters(ox, oy, nx, ny, obst)
            bad = np.flatnonzero(~ok)
            if bad.size:
                ex, ey = nx[bad] - ox[bad], ny[bad] - oy[bad]
                xfirst = np.abs(ex) >= np.abs(ey)
                bx, by = ox[bad], oy[bad]
                found = np.zeros(bad.size, dtype=bool)
                rx, ry = bx.copy(), by.copy()
                for first in (True, False):
                    use_x = xfirst if first else ~xfirst
                    cx = np.where(use_x, bx + ex, bx)
                    cy = np.where(use_x, by, by + ey)
                    good = (
                        ~found
                        & ((cx != bx) | (cy != by))
                        & self._footprint_free(cx, cy)
                        & ~self._enters(bx, by, cx, cy, obst)
                    )
                    rx = np.where(good, cx, rx)
                    ry = np.where(good, cy, ry)
                    found |= good
                nx[bad] = rx
                ny[bad] = ry
                ok[bad] = found
            okm = mv[ok]
            step_len = np.hypot(nx[ok] - ox[ok], ny[ok] - oy[ok])
            ds[okm] = np.copysign(step_len, ds[okm])
            v[okm] = ds[okm] / dt
            x[okm] = nx[ok]
            y[okm] = ny[ok]
            moved[okm] = True
            nok = mv[~ok]
            ds[nok] = 0.0
            v[nok] = 0.0
        s.th[:n] = (th + dth + math.pi) % (2.0 * math.pi) - math.pi
        s.v[:n] = v
        s.w[:n] = w
        adist = np.abs(ds)
        s.dist[:n] += adist
        for robot in py_robots:
            task = robot.task
            if task is not None:
                task.after_move(float(ds[robot.index]), float(dth[robot.index]))
        # 5. battery
        b = p.battery
        charging = np.zeros(n, dtype=bool)
        if self._chargers.shape[0]:
            idle = np.flatnonzero(~moved & (w == 0.0))
            if idle.size:
                cx = self._chargers[:, 0]
                cy = self._chargers[:, 1]
                near = np.hypot(cx[None, :] - x[idle, None], cy[None, :] - y[idle, None]) <= p.charger_radius
                charging[idle] = near.any(axis=1)
        bat = s.battery[:n]
        s.battery[:n] = np.where(
            charging,
            np.minimum(1.0, bat + b.charge_per_s * dt),
            np.maximum(0.0, bat - b.drain_per_m * adist - b.drain_per_s * dt),
        )
        s.charging[:n] = charging
        # 6. stuck detector (progress checker)
        far = np.hypot(x - s.px[:n], y - s.py[:n]) > PROGRESS_RADIUS_M
        if far.any():
            s.px[:n][far] = x[far]
            s.py[:n][far] = y[far]
            s.pt[:n][far] = now
            s.stuck[:n][far] = False
        trying = s.has_task[:n] & s.drives[:n]
        s.pt[:n][~far & ~trying] = now
        stuck = np.flatnonzero(~far & trying & (now - s.pt[:n] >= p.stuck_time_s - 1e-9))
        for i in stuck.tolist():
            robot = self._order[i]
            s.stuck[i] = True
            s.pt[i] = now
            task = robot.task
            if task is not None:
                task.on_stuck()
                self._task_changed(robot)
        # 7. contacts
        self._count_contacts(now, pi, pj)
        if now >= self._next_sample - 1e-9:
            self._samples_t.append(now)
            self._samples_xy.append(np.stack((x, y), axis=1))
            while self._next_sample <= now + 1e-9:
                self._next_sample += TRAJECTORY_PERIOD_S

    # -- vectorized pieces ----------------------------------------------------------

    def _footprint_free(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        g = self.grid
        ix = np.floor((x - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((y - g.origin_y) / g.resolution).astype(np.int64)
        inside = (ix >= 0) & (iy >= 0) & (ix < g.width) & (iy < g.height)
        flat = np.where(inside, iy * g.width + ix, 0)
        return inside & ~self._fp_flat[flat]

    def _enters(
        self, ox: np.ndarray, oy: np.ndarray, nx: np.ndarray, ny: np.ndarray, obst: np.ndarray
    ) -> np.ndarray:
        """True where the move from ``(ox, oy)`` to ``(nx, ny)`` ends inside a dynamic
        obstacle (within radius + obstacle radius) and closer to it than before."""
        out = np.zeros(ox.shape, dtype=bool)
        r = self.params.model.radius
        for qx, qy, qr in obst.tolist():
            d_new = np.hypot(nx - qx, ny - qy)
            out |= (d_new < r + qr) & (d_new < np.hypot(ox - qx, oy - qy))
        return out

    def _free_dynamic(
        self,
        idx: np.ndarray,
        hx: np.ndarray,
        hy: np.ndarray,
        cap: np.ndarray,
        pi: np.ndarray,
        pj: np.ndarray,
        obst: np.ndarray,
        n: int,
    ) -> np.ndarray:
        """For robots ``idx`` heading along unit ``(hx, hy)`` (arrays over ``idx``, any extra
        trailing shape broadcast against ``cap``): distance to the first robot or dynamic
        obstacle in the corridor ahead, capped at ``cap``."""
        r = self.params.model.radius
        contact = 2.0 * r
        best = np.array(np.broadcast_to(cap, hx.shape), dtype=float)
        if pi.size:
            reach = math.hypot(float(best.max()) + contact, contact + CORRIDOR_MARGIN_M)
            near = self._pd2 < reach * reach if reach < self._pair_radius else None
            if idx.size == n:
                a, dx, dy = pi, self._pdx, self._pdy
                if near is not None:
                    a, dx, dy = a[near], dx[near], dy[near]
            else:
                loc = np.full(n, -1, dtype=np.int64)
                loc[idx] = np.arange(idx.size)
                a = loc[pi]
                sel = a >= 0 if near is None else (a >= 0) & near
                a, dx, dy = a[sel], self._pdx[sel], self._pdy[sel]
            if a.size:
                extra = hx.ndim - 1
                if extra:
                    dx = dx.reshape(dx.shape + (1,) * extra)
                    dy = dy.reshape(dy.shape + (1,) * extra)
                hxa, hya = hx[a], hy[a]
                along = dx * hxa + dy * hya
                lateral = np.abs(dx * hya - dy * hxa)
                # only what is ahead, in the corridor and closer than the cap can limit
                hit = np.nonzero(
                    (along > 0.0) & (lateral < contact + CORRIDOR_MARGIN_M) & (along < best[a] + contact)
                )
                if hit[0].size:
                    al, la = along[hit], lateral[hit]
                    inner = al - np.sqrt(np.maximum(contact * contact - la * la, 0.0))
                    gap = np.maximum(0.0, np.where(la >= contact, al - contact, inner))
                    rows = (a[hit[0]],) + hit[1:]
                    np.minimum.at(best, rows, gap)
        sx = self.state.x[idx]
        sy = self.state.y[idx]
        extra = hx.ndim - 1
        for qx, qy, qr in obst.tolist():
            dx = (qx - sx).reshape(sx.shape + (1,) * extra)
            dy = (qy - sy).reshape(sy.shape + (1,) * extra)
            best = np.minimum(best, _corridor_gaps(dx, dy, hx, hy, r + qr, best))
        return best

    def _follow(self, F: np.ndarray, now: float, pi: np.ndarray, pj: np.ndarray, obst: np.ndarray) -> None:
        """The path follower of every robot in ``F`` (indices), vectorized: progress along the
        path, passed vias, arrival, lookahead target, avoidance detours, turn-then-drive
        command and the approach timer. Arrivals and approach timeouts call the robot's task."""
        s = self.state
        p = self.params
        m = p.model
        tol = p.goal_tolerance
        n = s.n
        X, Y, TH = s.x[F], s.y[F], s.th[F]
        PX, PY, SL, SUF = s.pts_x, s.pts_y, s.seg_len, s.suffix
        off = s.f_off[F]
        last = s.f_len[F] - 2
        seg = s.f_seg[F].copy()
        xy = s.f_xy[F].copy()
        act = ~xy
        # progress along the path: next segment once past the segment's end or within the
        # goal tolerance of it (so sharp turns cannot make the robot orbit the corner)
        while True:
            k = off + seg
            ax, ay, bx, by = PX[k], PY[k], PX[k + 1], PY[k + 1]
            L = SL[k]
            ex, ey = bx - ax, by - ay
            t = np.where(L > 1e-9, ((X - ax) * ex + (Y - ay) * ey) / np.maximum(L * L, 1e-18), 1.0)
            adv = act & (seg < last) & ((t >= 1.0) | (np.hypot(bx - X, by - Y) <= tol))
            if not adv.any():
                break
            seg += adv
        proj = np.clip(t, 0.0, 1.0)
        # vias passed: the path reached them, or the robot came within the tolerance
        nv = s.f_nv[F].copy()
        vn = s.f_vn[F]
        voff = s.f_voff[F]
        while True:
            can = act & (nv < vn - 1)
            if not can.any():
                break
            vi = s.vias[voff + np.minimum(nv, vn - 1)]
            adv = can & ((seg >= vi) | (np.hypot(PX[off + vi] - X, PY[off + vi] - Y) <= tol))
            if not adv.any():
                break
            nv += adv
        gk = off + last + 1
        xy |= act & (nv >= vn - 1) & (np.hypot(PX[gk] - X, PY[gk] - Y) <= tol)
        vcmd = np.zeros(F.size)
        wcmd = np.zeros(F.size)
        arrived = np.zeros(F.size, dtype=bool)
        # final yaw
        yi = np.flatnonzero(xy)
        if yi.size:
            err = (s.f_yaw[F[yi]] - TH[yi] + math.pi) % (2.0 * math.pi) - math.pi
            done = np.abs(err) <= p.yaw_tolerance
            arrived[yi[done]] = True
            turn = np.minimum(m.max_angular_speed, np.sqrt(2.0 * m.max_angular_accel * np.abs(err)))
            wcmd[yi] = np.where(done, 0.0, np.copysign(turn, err))
        # driving along the path
        di = np.flatnonzero(~xy)
        rem = np.zeros(F.size)
        side = s.f_side[F].copy()
        if di.size:
            k = off[di] + seg[di]
            ax, ay, bx, by = PX[k], PY[k], PX[k + 1], PY[k + 1]
            tq = proj[di]
            qx, qy = ax + tq * (bx - ax), ay + tq * (by - ay)
            Xd, Yd = X[di], Y[di]
            rem_d = np.hypot(bx - qx, by - qy) + SUF[k + 1] + np.hypot(qx - Xd, qy - Yd)
            rem[di] = rem_d
            # lookahead point 0.3 + 0.3 |v| ahead along the path
            dist = 0.3 + 0.3 * np.abs(s.v[F[di]])
            left = np.hypot(bx - qx, by - qy)
            lastd = last[di]
            segk = seg[di].copy()
            while True:
                more = (dist > left) & (segk < lastd)
                if not more.any():
                    break
                dist = np.where(more, dist - left, dist)
                segk += more
                kk = off[di] + segk
                qx = np.where(more, PX[kk], qx)
                qy = np.where(more, PY[kk], qy)
                bx = np.where(more, PX[kk + 1], bx)
                by = np.where(more, PY[kk + 1], by)
                left = np.where(more, SL[kk], left)
            f = np.where(dist >= left, 1.0, dist / np.maximum(left, 1e-12))
            tx, ty = qx + f * (bx - qx), qy + f * (by - qy)
            desired = np.arctan2(ty - Yd, tx - Xd)
            # local avoidance: detour around robots / dynamic obstacles in the way
            fi = F[di]
            blk = self._free_dynamic(
                fi, np.cos(desired), np.sin(desired), np.full(di.size, AVOID_LOOKAHEAD_M), pi, pj, obst, n
            )
            blocked = (blk < AVOID_LOOKAHEAD_M) & (blk + 2.0 * m.radius + tol < rem_d)
            sd = side[di]
            sd[~blocked] = 0
            bi = np.flatnonzero(blocked)
            if bi.size:
                fb = fi[bi]
                heads = desired[bi, None] + _OFFSETS[None, :]
                hx, hy = np.cos(heads), np.sin(heads)
                free = self._free_dynamic(fb, hx, hy, np.full(heads.shape, AVOID_CLEAR_M), pi, pj, obst, n)
                ok = free >= AVOID_CLEAR_M
                rb, ro = np.nonzero(ok)
                if rb.size:
                    smp = self._clear_samples
                    cx = s.x[fb[rb]][:, None] + hx[rb, ro][:, None] * smp[None, :]
                    cy = s.y[fb[rb]][:, None] + hy[rb, ro][:, None] * smp[None, :]
                    ok[rb, ro] = self._footprint_free(cx, cy).all(axis=1)
                order = _ORDERS[sd[bi] + 1]
                ok_ord = np.take_along_axis(ok, order, axis=1)
                anyok = ok_ord.any(axis=1)
                first = np.argmax(ok_ord, axis=1)
                chosen = _OFFSETS[order[np.arange(bi.size), first]]
                desired[bi] = np.where(anyok, desired[bi] + chosen, desired[bi])
                sd[bi] = np.where(anyok, np.where(chosen > 0, 1, -1), sd[bi])
            side[di] = sd
            err = (desired - TH[di] + math.pi) % (2.0 * math.pi) - math.pi
            aerr = np.abs(err)
            rot = aerr > ROTATE_IN_PLACE_RAD
            turn = np.minimum(m.max_angular_speed, np.sqrt(2.0 * m.max_angular_accel * aerr))
            vdrive = m.max_linear_speed * (1.0 - 0.6 * aerr / ROTATE_IN_PLACE_RAD)
            vdrive = np.minimum(vdrive, np.sqrt(2.0 * m.max_linear_accel * 0.8 * rem_d))
            wdrive = np.clip(HEADING_GAIN * err, -m.max_angular_speed, m.max_angular_speed)
            vcmd[di] = np.where(rot, 0.0, vdrive)
            wcmd[di] = np.where(rot, np.copysign(turn, err), wdrive)
        # approach timer: the remaining path must shrink by APPROACH_M every window
        best = s.f_best[F]
        btime = s.f_btime[F]
        better = xy | (rem < best - APPROACH_M)
        best = np.where(better, rem, best)
        btime = np.where(better, now, btime)
        window = APPROACH_FACTOR * p.stuck_time_s
        timeout = ~arrived & (now - btime >= window - 1e-9)
        # write back
        s.f_seg[F] = seg
        s.f_t[F] = proj
        s.f_nv[F] = nv
        s.f_xy[F] = xy
        s.f_side[F] = side
        s.f_best[F] = best
        s.f_btime[F] = btime
        stop = arrived | timeout
        vcmd[stop] = 0.0
        wcmd[stop] = 0.0
        s.vd[F] = vcmd
        s.wd[F] = wcmd
        s.drives[F] = vcmd != 0.0
        for a in np.flatnonzero(stop).tolist():
            robot = self._order[int(F[a])]
            task = robot.task
            if task is None:
                continue
            if arrived[a]:
                task.arrived(now)
            else:
                task.no_approach(now)
            s.drives[robot.index] = task.drives if not s.fol[robot.index] else False
            self._task_changed(robot)

    def free_distance(
        self, robot: Robot, direction: float, lookahead: float, static: bool, heading: float | None = None
    ) -> float:
        """Distance (m) the center of ``robot`` can travel straight along ``heading`` (default:
        its current yaw; ``direction`` +1 forward, -1 backward) before its footprint touches
        another robot or a dynamic obstacle (and, if ``static``, a static obstacle or the map
        edge), capped at ``lookahead``. Only things in the corridor of the robot's width ahead
        count."""
        r = self.params.model.radius
        s = self.state
        n = s.n
        i = robot.index
        yaw = float(s.th[i]) if heading is None else heading
        hx = math.cos(yaw) * direction
        hy = math.sin(yaw) * direction
        x, y = float(s.x[i]), float(s.y[i])
        others = np.ones(n, dtype=bool)
        others[i] = False
        dx = s.x[:n][others] - x
        dy = s.y[:n][others] - y
        best = lookahead
        if dx.size:
            best = min(
                best, float(_corridor_gaps(dx, dy, hx, hy, 2.0 * r, np.full(dx.size, lookahead)).min())
            )
        for ox, oy, orad in self._obstacles.values():
            g = _corridor_gaps(np.array([ox - x]), np.array([oy - y]), hx, hy, r + orad, np.array([best]))
            best = min(best, float(g[0]))
        if static and best > 0.0:
            stepd = 0.5 * self.grid.resolution
            sd = stepd
            while sd <= best:
                if not self.planner.footprint_free(x + hx * sd, y + hy * sd):
                    best = max(0.0, sd - stepd)
                    break
                sd += stepd
        return best

    def _count_contacts(self, now: float, pi: np.ndarray, pj: np.ndarray) -> None:
        s = self.state
        d2 = 2.0 * self.params.model.radius
        m = self.params.model
        # a pair touching now was closer than 2 * radius + both robots' longest step before it
        before = d2 + 2.0 * m.max_linear_speed * self.params.step_s + 1e-6
        half = (pi < pj) & (self._pd2 < before * before)
        a, b = pi[half], pj[half]
        close = np.hypot(s.x[b] - s.x[a], s.y[b] - s.y[a]) < d2
        touching = set(zip(a[close].tolist(), b[close].tolist(), strict=True))
        new = touching - self._touching
        if new:
            named = []
            for i, j in new:
                na, nb = self._order[i].namespace, self._order[j].namespace
                named.append((na, nb, i, j) if na < nb else (nb, na, j, i))
            for na, nb, i, j in sorted(named):
                s.collisions[i] += 1
                s.collisions[j] += 1
                self.collisions += 1
                self.collision_events.append(
                    (now, na, nb, 0.5 * float(s.x[i] + s.x[j]), 0.5 * float(s.y[i] + s.y[j]))
                )
        self._touching = touching


#: Detour offsets and the order they are tried in, by the side already chosen (-1, 0, +1).
_OFFSETS = np.array(AVOID_OFFSETS)
_ORDERS = np.array(
    [
        [k for k, o in enumerate(AVOID_OFFSETS) if o < 0] + [k for k, o in enumerate(AVOID_OFFSETS) if o > 0],
        list(range(len(AVOID_OFFSETS))),
        [k for k, o in enumerate(AVOID_OFFSETS) if o > 0] + [k for k, o in enumerate(AVOID_OFFSETS) if o < 0],
    ],
    dtype=np.int64,
)


def _corridor_gaps(
    dx: np.ndarray,
    dy: np.ndarray,
    hx: np.ndarray | float,
    hy: np.ndarray | float,
    contact: float,
    cap: np.ndarray,
) -> np.ndarray:
    """How far along unit heading ``(hx, hy)`` a disc can move before its center comes within
    ``contact`` of a point at offset ``(dx, dy)``; ``cap`` where the point is not ahead in the
    corridor; 0 if already in contact and the point is ahead. Element-wise."""
    along = dx * hx + dy * hy
    lateral = np.abs(dx * hy - dy * hx)
    inner = along - np.sqrt(np.maximum(contact * contact - lateral * lateral, 0.0))
    gap = np.maximum(0.0, np.where(lateral >= contact, along - contact, inner))
    return np.where((along <= 0.0) | (lateral >= contact + CORRIDOR_MARGIN_M), cap, gap)


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
