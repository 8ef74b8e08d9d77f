"""The kinematic multi-robot simulator: a fixed-step world of differential-drive robots that
stands in for a fleet of Nav2 robots.

One :class:`Simulator` owns the robots, the static map (an
:class:`~fleet.maps.OccupancyGrid`), dynamic round obstacles and every goal ever sent. Time
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
2. acceleration limits of :class:`~fleet.robots.RobotModel` are applied;
3. the reactive safety layer limits ``v`` so the robot can stop :data:`STOP_GAP_M` before
   another robot or dynamic obstacle in the corridor ahead in its direction of travel (what
   Nav2's local costmap / collision monitor do);
4. a stalled robot or an empty battery does not move; motion that would put the robot's
   footprint on a static obstacle (or off the map) or into a dynamic obstacle is refused
   (sliding along it when one axis of the move is free);
5. odometer, battery (drain or charge) and the stuck detector are updated.

Then robot-robot contacts (center distance < 2 * radius) are counted: a pair that starts
touching is one collision event. Robot pairs that can matter (closer than about 2.2 m) come
from a uniform-grid spatial hash (:func:`sim.spatial.neighbor_pairs`, a Verlet list rebuilt
every :data:`PAIR_REUSE_STEPS` steps), and robots see each other where they were at the start
of the step.

The cost of a step is NumPy calls, so the step keeps their number and size down without
changing a single float of the result: the path follower reads each robot's current segment
from a cache refreshed only when the segment changes and runs later rounds of its cursor loops
only over the robots that advanced; corridor checks run over all pairs at once with a zero
heading for robots outside the set checked; the detour search judges most (pair, heading)
combinations in closed form (:meth:`Simulator._detour_blocks`) and skips the static footprint
samples for robots far from any obstacle. Snapshots for polling (:meth:`Simulator.goal_state`,
:meth:`Simulator.robot_state`) read one row copied out of the arrays once per step.

Goals are addressed by ids ``"<namespace>#<n>"``, never reused. See ``docs/simulator.md``
for the action semantics and error codes.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fleet.clock import SimClock, step_until
from fleet.errors import BackendError
from fleet.maps import OccupancyGrid
from fleet.robots import RobotSpec, SimParams
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
from sim.backend import NamespacedBackend
from sim.planner import GridPlanner, inflate
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
    frozen_factory,
)
from sim.spatial import neighbor_pairs
from sim.state import FleetState

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
        self._backends: dict[str, NamespacedBackend] = {}
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
        contact = 2.0 * m.radius
        lat = contact + CORRIDOR_MARGIN_M
        #: pairs closer than this (detour and safety-stop corridors, contacts) are also kept
        #: in a shorter list every step
        self._short_r = (
            max(
                math.hypot(AVOID_CLEAR_M + contact, lat),
                math.hypot(look_max + contact, lat),
                contact + 2.0 * vmax * params.step_s + 1e-6,
            )
            + 1e-6
        )
        self._sa = self._sb = self._pi
        self._sdx = self._sdy = self._sd2 = self._pd2
        self._obst = np.zeros((0, 3))
        padded = np.zeros((grid.height + 2, grid.width + 2), dtype=bool)
        padded[1:-1, 1:-1] = ~self.planner.footprint
        #: footprint-free cells with a blocked border (off the map is not free)
        self._fp_free_padded = padded.ravel()
        self._clear_free: np.ndarray | None = None
        #: the closed-form judgement of detour headings (:meth:`_detour_blocks`) holds when the
        #: corridor is narrower than the detour clearance; pairs are judged that way unless
        #: their distance is within _DIST_MARGIN of where the blocked intervals change shape
        #: (a table over the distance, conservative by a bin on either side)
        self._judged: np.ndarray | None = None
        if 0.0 < contact and lat < AVOID_CLEAR_M and lat < math.hypot(contact, AVOID_CLEAR_M):
            reach_d = math.hypot(AVOID_CLEAR_M + contact, lat)
            lo = (np.arange(int(reach_d / _JUDGED_BIN) + 3) - 1.0) * _JUDGED_BIN
            hi = lo + 3.0 * _JUDGED_BIN
            judged = lo > _DIST_MARGIN
            for crit in (lat, math.hypot(contact, AVOID_CLEAR_M), contact + AVOID_CLEAR_M):
                judged &= (hi < crit - _DIST_MARGIN) | (lo > crit + _DIST_MARGIN)
            self._judged = judged
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
        x, y, th, v, w, battery, charging, stuck, dist, collisions = self.state.row(
            self._robot(namespace).index
        )[:10]
        return _make_robot_state(
            pose=Pose2D(x, y, th),
            linear_velocity=v,
            angular_velocity=w,
            battery=battery,
            charging=bool(charging),
            stuck=bool(stuck),
            distance_m=dist,
            collisions=int(collisions),
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

    def backend(self, namespace: str) -> NamespacedBackend:
        """A :class:`~fleet.navigation.NavigationBackend` for robot ``namespace``."""
        self._robot(namespace)
        b = self._backends.get(namespace)
        if b is None:
            b = NamespacedBackend(self, namespace)
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
        self._obst = self._obstacle_array()
        return oid

    def remove_obstacle(self, obstacle_id: int) -> None:
        """Remove a dynamic obstacle; unknown ids are ignored."""
        self._obstacles.pop(obstacle_id, None)
        self._obst = self._obstacle_array()

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
        if not record.terminal:
            task = self._robots[record.namespace].task
            if task is not None and task.record is record:
                return record.snapshot(task.feedback())
        return record.snapshot()

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id``: it ends CANCELED at once and the robot decelerates to a stop.
        A no-op for a finished or unknown goal."""
        record = self._goals.get(goal_id)
        if record is None or record.terminal:
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

    def path_progress(self, robot: Robot) -> tuple[float, float, float, float, int]:
        """Pose, remaining path length and poses left of ``robot`` (see :class:`sim.robot.World`)."""
        return self.state.progress(robot.index)

    # -- stepping ---------------------------------------------------------------------

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Step until ``predicate()`` is true (checked before each step) or ``timeout_s``
        simulated seconds have passed. Returns whether the predicate became true."""
        return step_until(self.clock, self.step, predicate, timeout_s)

    def step(self) -> None:
        """Advance the clock by ``params.step_s`` and move every robot (see module docstring)."""
        s = self.state
        s.version += 1
        s.busy = True
        try:
            self._step()
        finally:
            s.version += 1
            s.busy = False

    def _step(self) -> None:
        p = self.params
        dt = p.step_s
        now = self.clock.advance(dt)
        self.steps += 1
        s = self.state
        n = s.n
        if n == 0:
            return
        self._update_pairs(n, dt)
        obst = self._obst
        vd = s.vd[:n]
        wd = s.wd[:n]
        vd[:] = 0.0
        wd[:] = 0.0
        # 1. commands: Python tasks (rare: Spin, BackUp, Wait, between waypoints) ...
        py_robots = [self._py[i] for i in sorted(self._py)] if self._py else []
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
            self._follow(fol, now, obst)
        # 2. acceleration and speed limits, faults
        m = p.model
        dv = m.max_linear_accel * dt
        dw = m.max_angular_accel * dt
        v0 = s.v[:n]
        w0 = s.w[:n]
        v = np.maximum(vd, v0 - dv)
        np.minimum(v, v0 + dv, out=v)
        np.maximum(v, -m.max_linear_speed, out=v)
        np.minimum(v, m.max_linear_speed, out=v)
        w = np.maximum(wd, w0 - dw)
        np.minimum(w, w0 + dw, out=w)
        np.maximum(w, -m.max_angular_speed, out=w)
        np.minimum(w, m.max_angular_speed, out=w)
        dead = s.stalled[:n] | (s.battery[:n] <= 0.0)
        if dead.any():
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
            thm = th[mv]
            hx = np.cos(thm) * direction
            hy = np.sin(thm) * direction
            free = self._corridor_free(mv, hx, hy, look, obst)
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
            dsm = ds[mv]
            nx = ox + dsm * np.cos(mid)
            ny = oy + dsm * np.sin(mid)
            ok = self._footprint_free(nx, ny)
            if obst.size:
                ok &= ~self._enters(ox, oy, nx, ny, obst)
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
                    good = ~found & ((cx != bx) | (cy != by)) & self._footprint_free(cx, cy)
                    if obst.size:
                        good &= ~self._enters(bx, by, cx, cy, obst)
                    rx = np.where(good, cx, rx)
                    ry = np.where(good, cy, ry)
                    found |= good
                nx[bad] = rx
                ny[bad] = ry
                ok[bad] = found
                okm = mv[ok]
                nx, ny, ox, oy = nx[ok], ny[ok], ox[ok], oy[ok]
                nok = mv[~ok]
                ds[nok] = 0.0
                v[nok] = 0.0
            else:
                okm = mv
            step_len = np.hypot(nx - ox, ny - oy)
            dsk = np.copysign(step_len, ds[okm])
            ds[okm] = dsk
            v[okm] = dsk / dt
            x[okm] = nx
            y[okm] = ny
            moved[okm] = True
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
        px, py, pt = s.px[:n], s.py[:n], s.pt[:n]
        far = np.hypot(x - px, y - py) > PROGRESS_RADIUS_M
        if far.any():
            np.copyto(px, x, where=far)
            np.copyto(py, y, where=far)
            pt[far] = now
            s.stuck[:n][far] = False
        near_p = ~far
        trying = s.has_task[:n] & s.drives[:n]
        pt[near_p & ~trying] = now
        stuck = np.flatnonzero(near_p & trying & (now - pt >= p.stuck_time_s - 1e-9))
        for i in stuck.tolist():
            robot = self._order[i]
            s.stuck[i] = True
            s.pt[i] = now
            task = robot.task
            if task is not None:
                task.on_stuck()
                self._task_changed(robot)
        # 7. contacts
        self._count_contacts(now)
        if now >= self._next_sample - 1e-9:
            self._samples_t.append(now)
            self._samples_xy.append(np.stack((x, y), axis=1))
            while self._next_sample <= now + 1e-9:
                self._next_sample += TRAJECTORY_PERIOD_S

    # -- vectorized pieces ----------------------------------------------------------

    def _update_pairs(self, n: int, dt: float) -> None:
        """Refresh the neighbor pairs (a Verlet list, rebuilt every :data:`PAIR_REUSE_STEPS`
        steps) and their offsets ``x[j] - x[i]`` at the start of the step; keep the pairs
        closer than the short radius (corridor checks of the detour search and the safety
        stop, contacts) in a second, shorter list."""
        s = self.state
        if n != self._pairs_n or self.steps - self._pairs_step >= PAIR_REUSE_STEPS:
            # pairs within the radius plus what PAIR_REUSE_STEPS steps can close
            skin = 2.0 * self.params.model.max_linear_speed * dt * PAIR_REUSE_STEPS
            self._pi, self._pj = neighbor_pairs(s.x[:n], s.y[:n], self._pair_radius + skin)
            self._pairs_n, self._pairs_step = n, self.steps
        pi, pj = self._pi, self._pj
        x = s.x[:n]
        y = s.y[:n]
        self._pdx = x[pj] - x[pi]
        self._pdy = y[pj] - y[pi]
        self._pd2 = self._pdx * self._pdx + self._pdy * self._pdy
        if self._short_r < self._pair_radius:
            near = np.flatnonzero(self._pd2 < self._short_r * self._short_r)
            self._sa, self._sb = pi[near], pj[near]
            self._sdx, self._sdy, self._sd2 = self._pdx[near], self._pdy[near], self._pd2[near]
        else:
            self._sa, self._sb, self._sdx, self._sdy, self._sd2 = pi, pj, self._pdx, self._pdy, self._pd2

    def _pairs_within(self, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(i, dx, dy, d2)`` of the directed pairs ``(i, j)`` that can matter to a corridor
        check reaching ``reach`` m: those with ``d2 < reach**2`` (every pair when the reach
        is beyond the pair radius)."""
        if reach >= self._pair_radius:
            return self._pi, self._pdx, self._pdy, self._pd2
        if reach <= self._short_r:
            a, dx, dy, d2 = self._sa, self._sdx, self._sdy, self._sd2
        else:
            a, dx, dy, d2 = self._pi, self._pdx, self._pdy, self._pd2
        near = np.flatnonzero(d2 < reach * reach)
        if near.size == a.size:
            return a, dx, dy, d2
        return a[near], dx[near], dy[near], d2[near]

    def _footprint_free(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where a robot centered at ``(x, y)`` overlaps no static obstacle and is on the
        map (element-wise; the padded footprint grid makes off-map cells blocked)."""
        g = self.grid
        ix = np.floor((x - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((y - g.origin_y) / g.resolution).astype(np.int64)
        np.minimum(np.maximum(ix, -1, out=ix), g.width, out=ix)
        np.minimum(np.maximum(iy, -1, out=iy), g.height, out=iy)
        iy += 1
        iy *= g.width + 2
        iy += ix
        iy += 1
        return self._fp_free_padded[iy]

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

    def _corridor_free(
        self, idx: np.ndarray, hx: np.ndarray, hy: np.ndarray, cap: np.ndarray, obst: np.ndarray
    ) -> np.ndarray:
        """For robots ``idx`` (increasing indices) heading along unit ``(hx, hy)`` (arrays over
        ``idx``): distance (m) to the first robot or dynamic obstacle in the corridor ahead,
        capped at ``cap`` (an array over ``idx``).

        Works on every neighbor pair at once: a robot outside ``idx`` gets the heading
        ``(0, 0)``, so nothing is ahead of it and its pairs find nothing."""
        s = self.state
        n = s.n
        r = self.params.model.radius
        contact = 2.0 * r
        lat = contact + CORRIDOR_MARGIN_M
        reach = math.hypot(float(cap.max()) + contact, lat)
        a, dx, dy, _ = self._pairs_within(reach)
        if idx.size == n:
            hxf, hyf, capf = hx, hy, cap
        else:
            hxf = np.zeros(n)
            hyf = np.zeros(n)
            capf = np.zeros(n)
            hxf[idx] = hx
            hyf[idx] = hy
            capf[idx] = cap
        best = capf.copy()
        if a.size:
            hxa = hxf[a]
            hya = hyf[a]
            along = dx * hxa + dy * hya
            lateral = np.abs(dx * hya - dy * hxa)
            # only what is ahead, in the corridor and closer than the cap can limit
            hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < capf[a] + contact))
            if hit.size:
                al, la = along[hit], lateral[hit]
                inner = al - np.sqrt(np.maximum(contact * contact - la * la, 0.0))
                gap = np.maximum(0.0, np.where(la >= contact, al - contact, inner))
                np.minimum.at(best, a[hit], gap)
        if idx.size != n:
            best = best[idx]
        if obst.size:
            sx = s.x[idx]
            sy = s.y[idx]
            for qx, qy, qr in obst.tolist():
                best = np.minimum(best, _corridor_gaps(qx - sx, qy - sy, hx, hy, r + qr, best))
        return best

    def _detour(self, fb: np.ndarray, db: np.ndarray, side: np.ndarray, obst: np.ndarray) -> np.ndarray:
        """The detour of each blocked robot ``fb[r]`` that wants to go along ``db[r]`` (rad):
        the index in ``_OFFSETS`` of the first offset, in the order ``_ORDERS[side[r] + 1]``,
        whose heading ``db[r] + offset`` is free of robots and dynamic obstacles for
        :data:`AVOID_CLEAR_M` and keeps the footprint off static obstacles along the way
        (footprint samples every half cell); -1 if there is none. "Free" is exactly what the
        corridor test of :meth:`_corridor_free` capped at ``AVOID_CLEAR_M`` decides.

        The blocked headings of each robot are a bit mask over the sorted offsets. Neighbor
        pairs are judged in the angle between a heading and the neighbor's bearing
        (:meth:`_detour_blocks`): for a neighbor at distance ``d`` the blocked headings form at
        most three intervals with closed-form ends, so a pair sets the bits of the offsets well
        inside them without any per-heading arithmetic; offsets within :data:`_ANGLE_MARGIN`
        of an end, and every heading of a pair whose ``d`` is near a distance where the
        intervals change shape, get the exact test. A robot whose cell has no blocked
        footprint cell within ``AVOID_CLEAR_M`` + a cell diagonal cannot meet a static obstacle
        on any heading; only the others sample their free headings on the footprint grid.
        The first free offset in order comes from a table over (side, mask)."""
        s = self.state
        n = s.n
        nb = fb.size
        kk = _OFFSETS.size
        r = self.params.model.radius
        contact = 2.0 * r
        lat = contact + CORRIDOR_MARGIN_M
        cap = AVOID_CLEAR_M

        def unit(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """``(cos, sin)`` of the headings ``db[r] + _OFFSETS[k]`` at ``flat = r * K + k``."""
            h = db[flat // kk] + _OFFSETS[flat % kk]
            return np.cos(h), np.sin(h)

        blocked = np.zeros(nb, dtype=np.int64)  # bit j: the j-th smallest offset is blocked
        a_all, dx_all, dy_all, d2_all = self._pairs_within(math.hypot(cap + contact, lat))
        loc = np.full(n, -1, dtype=np.int64)
        loc[fb] = np.arange(nb)
        a = loc[a_all]
        sel = np.flatnonzero(a >= 0)
        if sel.size:
            a = a[sel]
            dx = dx_all[sel]
            dy = dy_all[sel]
            d = np.sqrt(d2_all[sel])
            rho = np.arctan2(dy, dx) - db[a]  # bearing of the neighbor from db, in [-2 pi, 2 pi]
            sure, slots_p, slots = self._detour_blocks(d, rho)
            if sure is not None:
                np.bitwise_or.at(blocked, a, sure)
            if slots.size:
                # the exact corridor test of _corridor_free for the (pair, heading) left over
                ap = a[slots_p]
                hxc, hyc = unit(ap * kk + _EXT_K[slots])
                dxc = dx[slots_p]
                dyc = dy[slots_p]
                along = dxc * hxc + dyc * hyc
                lateral = np.abs(dxc * hyc - dyc * hxc)
                hit = np.flatnonzero((along > 0.0) & (lateral < lat) & (along < cap + contact))
                if hit.size:
                    al, la = along[hit], lateral[hit]
                    inner = al - np.sqrt(np.maximum(contact * contact - la * la, 0.0))
                    gap = np.maximum(0.0, np.where(la >= contact, al - contact, inner))
                    bad = hit[gap < cap]
                    np.bitwise_or.at(blocked, ap[bad], np.left_shift(1, slots[bad] % kk))
        if obst.size:
            hx, hy = unit(np.arange(nb * kk))
            hx2 = hx.reshape(nb, kk)
            hy2 = hy.reshape(nb, kk)
            best = np.full((nb, kk), cap)
            sx = s.x[fb][:, None]
            sy = s.y[fb][:, None]
            for qx, qy, qr in obst.tolist():
                best = np.minimum(best, _corridor_gaps(qx - sx, qy - sy, hx2, hy2, r + qr, best))
            blocked |= ((best < cap)[:, _SORTED_K] * _BIT[None, :]).sum(axis=1)
        # static obstacles along the free headings, for robots not in the clear
        xb = s.x[fb]
        yb = s.y[fb]
        nc = np.flatnonzero(~self._in_clear(xb, yb))
        if nc.size:
            free = ((blocked[nc, None] >> _SORTED_POS[None, :]) & 1) == 0
            rb, ro = np.nonzero(free)
            if rb.size:
                rb = nc[rb]
                hx, hy = unit(rb * kk + ro)
                smp = self._clear_samples
                cx = xb[rb][:, None] + hx[:, None] * smp[None, :]
                cy = yb[rb][:, None] + hy[:, None] * smp[None, :]
                off = np.flatnonzero(~self._footprint_free(cx, cy).all(axis=1))
                if off.size:
                    np.bitwise_or.at(blocked, rb[off], _BIT[_SORTED_POS[ro[off]]])
        return _FIRST_FREE[side + 1, blocked]

    def _detour_blocks(
        self, d: np.ndarray, rho: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """Which detour offsets the neighbor of each pair blocks, for neighbors at distance
        ``d`` (m) and bearing ``rho`` (rad) relative to the robot's wanted heading. Returns
        ``(sure, pair, slot)``: ``sure[p]`` a bit mask over the sorted offsets that pair ``p``
        certainly blocks (``None`` if no pair was judged this way), and the (pair, slot of
        ``_EXT``) the exact test must still decide.

        With ``c`` the contact distance, ``lat`` the corridor half-width, ``cap`` =
        :data:`AVOID_CLEAR_M` and ``beta`` the angle from the neighbor's bearing to a heading,
        the corridor test blocks the heading iff (``t1 = d cos beta - sqrt(c^2 - d^2 sin^2
        beta)``, the distance at which the robot's disc touches the neighbor's; it grows with
        ``|beta|`` when ``d > c``):

        * ``d < lat``: ``|beta| < pi / 2``;
        * ``lat < d < hypot(c, cap)``: ``|beta| < asin(lat / d)``;
        * ``hypot(c, cap) < d < c + cap``: ``|beta| < acos((d^2 + cap^2 - c^2) / (2 cap d))``
          (where ``t1 = cap``) or ``asin(c / d) <= |beta| < asin(lat / d)`` (the band where
          the neighbor only grazes the corridor, blocked if it is closer than ``c + cap``
          along it, always here);
        * ``d > c + cap``: ``max(asin(c / d), acos((c + cap) / d)) <= |beta| < asin(lat / d)``.

        Offsets farther than :data:`_ANGLE_MARGIN` inside these intervals are blocked, those
        farther outside are not, whatever the rounding of the floats (it is below 1e-14 rad);
        the offsets within the margin of an end, and all offsets in the window of a pair whose
        ``d`` is within :data:`_DIST_MARGIN` of ``0``, ``lat``, ``hypot(c, cap)`` or ``c +
        cap`` (where the intervals change shape or an end moves fast with ``d``), go to the
        exact test."""
        contact = 2.0 * self.params.model.radius
        lat = contact + CORRIDOR_MARGIN_M
        cap = AVOID_CLEAR_M
        mid = math.hypot(contact, cap)
        far = contact + cap
        if self._judged is not None:
            # a table over d in bins of _JUDGED_BIN m: False near 0, lat, mid and far
            judged = self._judged[
                np.minimum((d * (1.0 / _JUDGED_BIN)).astype(np.int64), self._judged.size - 1)
            ]
            jp = np.flatnonzero(judged)
            xp = np.flatnonzero(~judged)
        else:
            jp = _EMPTY_INT
            xp = np.arange(d.size)
        sure: np.ndarray | None = None
        pairs: list[np.ndarray] = []
        slots: list[np.ndarray] = []
        if xp.size:
            # every offset in the window where the neighbor can be in the corridor at all
            dx_ = d[xp]
            w = np.where(dx_ > lat, np.arcsin(lat / np.maximum(dx_, lat)), 0.5 * math.pi) + _ANGLE_MARGIN
            rx = rho[xp]
            i0 = _EXT_BELOW[_ext_bin(rx - w)]
            cnt = _EXT_UPTO[_ext_bin(rx + w)] - i0
            tot = int(cnt.sum())
            if tot:
                pairs.append(np.repeat(xp, cnt))
                slots.append(np.repeat(i0 - (np.cumsum(cnt) - cnt), cnt) + np.arange(tot))
        if jp.size:
            dj = d[jp]
            b_lat = np.arcsin(np.minimum(lat / dj, 1.0))
            b_c = np.arcsin(np.minimum(contact / dj, 1.0))
            b_t1 = np.arccos(
                np.minimum((dj * dj + (cap * cap - contact * contact)) / ((2.0 * cap) * dj), 1.0)
            )
            b_along = np.arccos(np.minimum(far / dj, 1.0))
            c1 = dj < lat
            c4 = dj > far
            # central interval |beta| < half (0: none) and band lo <= |beta| < hi (lo >= hi: none)
            half = np.where(c1, 0.5 * math.pi, np.where(dj < mid, b_lat, np.where(c4, 0.0, b_t1)))
            band_lo = np.where(dj > mid, np.where(c4, np.maximum(b_c, b_along), b_c), b_lat + 1.0)
            m = _ANGLE_MARGIN
            inv = 1.0 / _EXT_BIN
            centre = (rho[jp] - _EXT_LO) * inv
            # a band down to nothing still gets its ends tested (it may hold an offset exactly)
            has_c = half > 0.0
            has_b = band_lo < b_lat + 2.0 * m
            # the three intervals in the angle of _EXT: the centre and the band on both sides;
            # the slots strictly inside by the margin (and the bin) are sure, the slots near
            # either end (by _NEAR_LO / _NEAR_HI) go to the exact test
            valid = np.stack((has_c, has_b, has_b))
            b0 = (centre + (np.stack((-half, band_lo, -b_lat)) + m) * inv).astype(np.int64)
            b1 = (centre + (np.stack((half, b_lat, -band_lo)) - m) * inv).astype(np.int64)
            s0 = _EXT_UPTO[b0]
            s1 = np.where(valid, np.maximum(_EXT_BELOW[b1], s0), s0)
            bits = np.left_shift(1, s1) - np.left_shift(1, s0)
            masks = bits[0] | bits[1] | bits[2]
            # fold the three copies of the offsets onto the sorted offsets
            k = _OFFSETS.size
            sure = (masks | (masks >> k) | (masks >> (2 * k))) & ((1 << k) - 1)
            near = np.concatenate((_NEAR_LO[b0], _NEAR_HI[b1]))
            q = np.flatnonzero((near >= 0) & np.concatenate((valid, valid)))
            if q.size:
                pairs.append(jp[q % jp.size])
                slots.append(near.ravel()[q])
            if jp.size != d.size:
                full = np.zeros(d.size, dtype=np.int64)
                full[jp] = sure
                sure = full
        if not pairs:
            return sure, _EMPTY_INT, _EMPTY_INT
        return sure, np.concatenate(pairs), np.concatenate(slots)

    def _in_clear(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where the cell of ``(x, y)`` has no blocked footprint cell (nor the map edge)
        within ``AVOID_CLEAR_M`` + a cell diagonal (center to center): every detour sample of
        a robot there is on a free cell. The grid is built on first use."""
        g = self.grid
        if self._clear_free is None:
            radius_cells = AVOID_CLEAR_M / g.resolution + math.sqrt(2.0) + 1e-3
            blocked = inflate(self.planner.footprint, radius_cells)
            padded = np.zeros((g.height + 2, g.width + 2), dtype=bool)
            padded[1:-1, 1:-1] = ~blocked
            self._clear_free = padded.ravel()
        ix = np.floor((x - g.origin_x) / g.resolution).astype(np.int64)
        iy = np.floor((y - g.origin_y) / g.resolution).astype(np.int64)
        np.minimum(np.maximum(ix, -1, out=ix), g.width, out=ix)
        np.minimum(np.maximum(iy, -1, out=iy), g.height, out=iy)
        return self._clear_free[(iy + 1) * (g.width + 2) + ix + 1]

    def _follow(self, F: np.ndarray, now: float, obst: np.ndarray) -> None:
        """The path follower of every robot in ``F`` (increasing indices), vectorized:
        progress along the path, passed vias, arrival, lookahead target, avoidance detours,
        turn-then-drive command and the approach timer. Arrivals and approach timeouts call
        the robot's task. Loops that advance a cursor (segment, via, lookahead) run their
        later rounds only over the robots that advanced."""
        s = self.state
        p = self.params
        m = p.model
        tol = p.goal_tolerance
        n = s.n
        full = F.size == n

        def get(arr: np.ndarray) -> np.ndarray:
            return arr[:n] if full else arr[F]

        X, Y = get(s.x), get(s.y)
        seg = get(s.f_seg).copy()
        last = get(s.f_len) - 2
        xy = get(s.f_xy).copy()
        act = ~xy
        # progress along the path: next segment once past the segment's end or within the
        # goal tolerance of it (so sharp turns cannot make the robot orbit the corner)
        ax, ay, bx, by, ex, ey = (get(c) for c in (s.c_ax, s.c_ay, s.c_bx, s.c_by, s.c_ex, s.c_ey))
        t = np.where(get(s.c_long), ((X - ax) * ex + (Y - ay) * ey) / get(s.c_den), 1.0)
        A = np.flatnonzero(act & (seg < last) & ((t >= 1.0) | (np.hypot(bx - X, by - Y) <= tol)))
        if A.size:
            while A.size:
                seg[A] += 1
                FA = F[A]
                s.f_seg[FA] = seg[A]
                s.load_segments(FA)
                XA, YA = X[A], Y[A]
                num = (XA - s.c_ax[FA]) * s.c_ex[FA] + (YA - s.c_ay[FA]) * s.c_ey[FA]
                tA = np.where(s.c_long[FA], num / s.c_den[FA], 1.0)
                t[A] = tA
                A = A[
                    (seg[A] < last[A]) & ((tA >= 1.0) | (np.hypot(s.c_bx[FA] - XA, s.c_by[FA] - YA) <= tol))
                ]
            if not full:
                ax, ay, bx, by, ex, ey = (get(c) for c in (s.c_ax, s.c_ay, s.c_bx, s.c_by, s.c_ex, s.c_ey))
        proj = np.minimum(np.maximum(t, 0.0), 1.0)
        # vias passed: the path reached them, or the robot came within the tolerance
        nv = get(s.f_nv).copy()
        can = act & get(s.c_vmore)
        A = np.flatnonzero(
            can & ((seg >= get(s.c_vseg)) | (np.hypot(get(s.c_vx) - X, get(s.c_vy) - Y) <= tol))
        )
        while A.size:
            nv[A] += 1
            FA = F[A]
            s.f_nv[FA] = nv[A]
            s.load_vias(FA)
            near = np.hypot(s.c_vx[FA] - X[A], s.c_vy[FA] - Y[A]) <= tol
            A = A[s.c_vmore[FA] & ((seg[A] >= s.c_vseg[FA]) | near)]
        xy |= act & ~get(s.c_vmore) & (np.hypot(get(s.c_gx) - X, get(s.c_gy) - Y) <= tol)
        vcmd = np.zeros(F.size)
        wcmd = np.zeros(F.size)
        arrived = np.zeros(F.size, dtype=bool)
        # final yaw
        yi = np.flatnonzero(xy)
        if yi.size:
            fy = F[yi]
            err = (s.f_yaw[fy] - s.th[fy] + math.pi) % (2.0 * math.pi) - math.pi
            done = np.abs(err) <= p.yaw_tolerance
            arrived[yi[done]] = True
            turn = np.minimum(m.max_angular_speed, np.sqrt(2.0 * m.max_angular_accel * np.abs(err)))
            wcmd[yi] = np.where(done, 0.0, np.copysign(turn, err))
        # driving along the path
        di = np.flatnonzero(~xy)
        rem = np.zeros(F.size)
        side = get(s.f_side).copy()
        if di.size:
            alld = di.size == F.size

            def sub(arr: np.ndarray) -> np.ndarray:
                return arr if alld else arr[di]

            fi = F if alld else F[di]
            tq = sub(proj)
            axd, ayd, bxd, byd = sub(ax), sub(ay), sub(bx), sub(by)
            qx = axd + tq * sub(ex)
            qy = ayd + tq * sub(ey)
            Xd, Yd = sub(X), sub(Y)
            left = np.hypot(bxd - qx, byd - qy)
            rem_d = left + sub(get(s.c_suf)) + np.hypot(qx - Xd, qy - Yd)
            if alld:
                rem = rem_d
            else:
                rem[di] = rem_d
            # lookahead point 0.3 + 0.3 |v| ahead along the path
            dist = 0.3 + 0.3 * np.abs(s.v[fi])
            segd = sub(seg)
            lastd = sub(last)
            M = np.flatnonzero((dist > left) & (segd < lastd))
            if M.size:
                PX, PY, SL = s.pts_x, s.pts_y, s.seg_len
                dM, lM, sM = dist[M], left[M], segd[M].copy()
                lastM = lastd[M]
                offM = s.f_off[fi[M]]
                qxM, qyM, bxM, byM = qx[M], qy[M], bxd[M], byd[M]
                more = np.ones(M.size, dtype=bool)
                while True:
                    dM = np.where(more, dM - lM, dM)
                    sM += more
                    kM = offM + sM
                    qxM = np.where(more, PX[kM], qxM)
                    qyM = np.where(more, PY[kM], qyM)
                    bxM = np.where(more, PX[kM + 1], bxM)
                    byM = np.where(more, PY[kM + 1], byM)
                    lM = np.where(more, SL[kM], lM)
                    more = (dM > lM) & (sM < lastM)
                    if not more.any():
                        break
                dist = dist.copy()
                left = left.copy()
                qx, qy, bxd, byd = qx.copy(), qy.copy(), bxd.copy(), byd.copy()
                dist[M], left[M], qx[M], qy[M], bxd[M], byd[M] = dM, lM, qxM, qyM, bxM, byM
            f = np.where(dist >= left, 1.0, dist / np.maximum(left, 1e-12))
            tx, ty = qx + f * (bxd - qx), qy + f * (byd - qy)
            desired = np.arctan2(ty - Yd, tx - Xd)
            # local avoidance: detour around robots / dynamic obstacles in the way
            blk = self._corridor_free(
                fi, np.cos(desired), np.sin(desired), np.full(di.size, AVOID_LOOKAHEAD_M), obst
            )
            blocked = (blk < AVOID_LOOKAHEAD_M) & (blk + 2.0 * m.radius + tol < rem_d)
            sd = side if alld else side[di]
            sd[~blocked] = 0
            bi = np.flatnonzero(blocked)
            if bi.size:
                db = desired[bi]
                sdb = sd[bi]
                k = self._detour(fi[bi], db, sdb, obst)
                anyok = k >= 0
                chosen = _OFFSETS[k]
                desired[bi] = np.where(anyok, db + chosen, db)
                sd[bi] = np.where(anyok, np.where(chosen > 0, 1, -1), sdb)
            if not alld:
                side[di] = sd
            err = (desired - sub(get(s.th)) + math.pi) % (2.0 * math.pi) - math.pi
            aerr = np.abs(err)
            rot = aerr > ROTATE_IN_PLACE_RAD
            turn = np.minimum(m.max_angular_speed, np.sqrt(2.0 * m.max_angular_accel * aerr))
            vdrive = m.max_linear_speed * (1.0 - 0.6 * aerr / ROTATE_IN_PLACE_RAD)
            vdrive = np.minimum(vdrive, np.sqrt(2.0 * m.max_linear_accel * 0.8 * rem_d))
            wdrive = np.clip(HEADING_GAIN * err, -m.max_angular_speed, m.max_angular_speed)
            vc = np.where(rot, 0.0, vdrive)
            wc = np.where(rot, np.copysign(turn, err), wdrive)
            if alld:
                vcmd, wcmd = vc, wc
            else:
                vcmd[di] = vc
                wcmd[di] = wc
        # approach timer: the remaining path must shrink by APPROACH_M every window
        best = get(s.f_best)
        btime = get(s.f_btime)
        better = xy | (rem < best - APPROACH_M)
        best = np.where(better, rem, best)
        btime = np.where(better, now, btime)
        window = APPROACH_FACTOR * p.stuck_time_s
        timeout = ~arrived & (now - btime >= window - 1e-9)
        stop = arrived | timeout
        any_stop = bool(stop.any())
        if any_stop:
            vcmd[stop] = 0.0
            wcmd[stop] = 0.0
        # write back
        if full:
            s.f_seg[:n] = seg
            s.f_t[:n] = proj
            s.f_nv[:n] = nv
            s.f_xy[:n] = xy
            s.f_side[:n] = side
            s.f_best[:n] = best
            s.f_btime[:n] = btime
            s.vd[:n] = vcmd
            s.wd[:n] = wcmd
            np.not_equal(vcmd, 0.0, out=s.drives[:n])
        else:
            s.f_seg[F] = seg
            s.f_t[F] = proj
            s.f_nv[F] = nv
            s.f_xy[F] = xy
            s.f_side[F] = side
            s.f_best[F] = best
            s.f_btime[F] = btime
            s.vd[F] = vcmd
            s.wd[F] = wcmd
            s.drives[F] = vcmd != 0.0
        if not any_stop:
            return
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

    def _count_contacts(self, now: float) -> None:
        s = self.state
        d2 = 2.0 * self.params.model.radius
        m = self.params.model
        # a pair touching now was closer than 2 * radius + both robots' longest step before it
        before = d2 + 2.0 * m.max_linear_speed * self.params.step_s + 1e-6
        if before <= self._short_r:
            pa, pb, pd2 = self._sa, self._sb, self._sd2
        else:
            pa, pb, pd2 = self._pi, self._pj, self._pd2
        half = np.flatnonzero((pa < pb) & (pd2 < before * before))
        a, b = pa[half], pb[half]
        close = np.hypot(s.x[b] - s.x[a], s.y[b] - s.y[a]) < d2
        touching = set(zip(a[close].tolist(), b[close].tolist(), strict=True)) if close.any() else set()
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


_make_robot_state = frozen_factory(RobotState)

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
#: The detour offsets sorted (``_SORTED_K``: the index in ``_OFFSETS`` of each; ``_SORTED_POS``
#: the inverse) and all their copies 2 pi below and above: ``_EXT``, sorted, is the three
#: sorted copies one after the other, so slot ``s`` is sorted offset ``s % K``.
_SORTED_K = np.argsort(_OFFSETS, kind="stable")
_SORTED_POS = np.argsort(_SORTED_K, kind="stable")
_EXT = np.concatenate(
    (_OFFSETS[_SORTED_K] - 2.0 * math.pi, _OFFSETS[_SORTED_K], _OFFSETS[_SORTED_K] + 2.0 * math.pi)
)
_EXT_K = np.tile(_SORTED_K, 3)
assert bool(np.all(np.diff(_EXT) > 0.0)), "the detour offsets must span less than 2 pi"
#: Angular margin (rad) far above the rounding of the angles involved (below 1e-14 rad): an
#: offset this far inside or outside an interval of blocked headings is judged without the
#: exact test; the window of a neighbor is widened by it.
_ANGLE_MARGIN = 1e-5
#: Distance margin (m) around the distances where the blocked intervals change shape, and the
#: bin of the table that finds the distances outside it.
_DIST_MARGIN = 1e-3
_JUDGED_BIN = 1e-4
#: Lookup tables over angles in [-4 pi, 4 pi], in bins of ``_EXT_BIN`` rad from ``_EXT_LO``:
#: ``_EXT_BELOW[b]`` / ``_EXT_UPTO[b]`` count the slots below the start / end of bin ``b``, so
#: ``[_EXT_BELOW[bin(lo)], _EXT_UPTO[bin(hi)])`` holds every slot in ``[lo, hi]`` (a few
#: more, maybe) and ``[_EXT_UPTO[bin(lo)], _EXT_BELOW[bin(hi)])`` only slots inside it;
#: ``_NEAR_LO[b]`` / ``_NEAR_HI[b]`` is the slot within ``3 * _ANGLE_MARGIN`` below / above
#: bin ``b`` (or in it, or one bin beyond, for rounding), -1 if none (slots are 0.35 rad apart).
_EXT_LO = -4.0 * math.pi
_EXT_BIN = 1.0 / 1024.0
_EXT_NBINS = int(8.0 * math.pi / _EXT_BIN) + 1
_EXT_EDGES = _EXT_LO + _EXT_BIN * np.arange(_EXT_NBINS + 1)
_EXT_BELOW = np.searchsorted(_EXT, _EXT_EDGES[:-1], "left")
_EXT_UPTO = np.searchsorted(_EXT, _EXT_EDGES[1:], "left")
_NEAR_LO = np.full(_EXT_NBINS, -1, dtype=np.int64)
_NEAR_HI = np.full(_EXT_NBINS, -1, dtype=np.int64)
for _s, _v in enumerate(_EXT.tolist()):
    _b = int((_v - _EXT_LO) / _EXT_BIN)
    _NEAR_LO[max(_b - 1, 0) : int((_v + 3.0 * _ANGLE_MARGIN - _EXT_LO) / _EXT_BIN) + 2] = _s
    _NEAR_HI[max(int((_v - 3.0 * _ANGLE_MARGIN - _EXT_LO) / _EXT_BIN) - 1, 0) : _b + 2] = _s
_EMPTY_INT = np.zeros(0, dtype=np.int64)
#: ``_BIT[j] = 1 << j``; ``_FIRST_FREE[side + 1, mask]``: the index in ``_OFFSETS`` of the first
#: offset in the order ``_ORDERS[side + 1]`` whose sorted position is not set in ``mask``, -1
#: if every one is.
_BIT = np.left_shift(1, np.arange(_OFFSETS.size, dtype=np.int64))
_FIRST_FREE = np.full((3, 1 << _OFFSETS.size), -1, dtype=np.int64)
for _i, _order in enumerate(_ORDERS):
    _free = ((np.arange(1 << _OFFSETS.size)[:, None] >> _SORTED_POS[_order][None, :]) & 1) == 0
    _FIRST_FREE[_i] = np.where(_free.any(axis=1), _order[_free.argmax(axis=1)], -1)


def _ext_bin(angle: np.ndarray) -> np.ndarray:
    """Bin of ``angle`` (rad, within [-4 pi, 4 pi]) in the ``_EXT_*`` tables."""
    b = ((angle - _EXT_LO) * (1.0 / _EXT_BIN)).astype(np.int64)
    return np.minimum(np.maximum(b, 0, out=b), _EXT_NBINS - 1, out=b)


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
