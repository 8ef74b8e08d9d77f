"""The kinematic multi-robot simulator: a fixed-step world of differential-drive robots that
stands in for a fleet of Nav2 robots.

One :class:`Simulator` owns the robots, the static map (an
:class:`~fleet.maps.OccupancyGrid`), dynamic round obstacles and every goal sent. Time is the
:class:`~fleet.clock.SimClock` passed in; :meth:`Simulator.step` advances it by
``params.step_s`` and moves every robot; nothing reads the wall clock and nothing is random,
so the same inputs give the same run.

The state lives in NumPy arrays (:class:`sim.state.FleetState`) and each step runs these
stages over all robots at once:

1. **goal dispatch** (:mod:`sim.dispatch`): goals that are not path following (Spin, BackUp,
   DriveOnHeading, Wait, FollowWaypoints between waypoints) run their Python
   :class:`sim.tasks.Task` in insertion order; then the **path follower**
   (:mod:`sim.follower`) commands every robot following a path (progress along the path,
   passed poses, lookahead target, turn-then-drive), with the **avoidance** detours of
   :mod:`sim.avoidance` around robots and dynamic obstacles. Tasks hear about arrivals,
   missing approach and stuck robots as events, never per step;
2. acceleration limits of :class:`~fleet.robots.RobotModel`, faults and an empty battery;
3. **safety** (:mod:`sim.safety`): the reactive stop limits ``v`` so the robot can stop
   :data:`~sim.safety.STOP_GAP_M` before another robot or dynamic obstacle in the corridor
   ahead (what Nav2's collision monitor does); the move is integrated, refusing motion that
   would put the footprint on a static obstacle (or off the map) or into a dynamic obstacle;
4. battery (:meth:`fleet.robots.BatteryModel.integrate`) and the stuck detector;
5. robot-robot contacts (center distance < 2 * radius; a pair that starts touching is one
   collision event).

Robot pairs that can matter (closer than about 2.2 m) come from a uniform-grid spatial hash
(:class:`sim.spatial.NeighborPairs`, a Verlet list rebuilt every few steps), and robots see
each other where they were at the start of the step. Snapshots for polling
(:meth:`Simulator.goal_state`, :meth:`Simulator.robot_state`) read one row copied out of the
arrays once per step.

Goals follow the shared Nav2 semantics of :mod:`sim.goals` (ids ``"<namespace>#<n>"``, never
reused). See ``docs/simulator.md`` for the action semantics and error codes.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fleet.clock import SimClock, step_until
from fleet.errors import BackendError
from fleet.maps import OccupancyGrid
from fleet.robots import RobotSpec, SimParams
from fleet.types import GoalState, Pose2D, RobotState, normalize_angle
from sim.avoidance import AVOID_CLEAR_M, AVOID_LOOKAHEAD_M, CORRIDOR_MARGIN_M, Avoidance
from sim.backend import NamespacedBackend
from sim.dispatch import GoalDispatch
from sim.follower import PathFollower
from sim.footprint import FootprintGrid
from sim.history import TRAJECTORY_KEEP_S, trim_oldest
from sim.planner import GridPlanner
from sim.robot import Robot
from sim.safety import STOP_GAP_M, Contacts, Safety
from sim.snapshots import make_robot_state
from sim.spatial import NeighborPairs
from sim.state import FleetState

#: A robot that moved this far (m) from where it last made progress has made progress.
PROGRESS_RADIUS_M = 0.1
#: Trajectories are sampled every this many simulated seconds.
TRAJECTORY_PERIOD_S = 0.5
#: Fault names accepted by :meth:`Simulator.set_fault`.
FAULTS = ("stalled",)


def pair_radii(params: SimParams) -> tuple[float, float]:
    """``(radius, short)`` (m) of the neighbor pairs: pairs closer than ``radius`` can matter
    to the avoidance and safety checks; pairs closer than ``short`` (detour and safety-stop
    corridors, contacts) are also kept in a shorter list every step."""
    m = params.model
    vmax = m.max_linear_speed
    look_max = vmax * vmax / (2.0 * m.max_linear_accel) + STOP_GAP_M + vmax * params.step_s + 0.05
    reach = max(AVOID_LOOKAHEAD_M, AVOID_CLEAR_M, look_max) + 2.0 * m.radius
    radius = math.hypot(reach, 2.0 * m.radius + CORRIDOR_MARGIN_M) + 0.01
    contact = 2.0 * m.radius
    lat = contact + CORRIDOR_MARGIN_M
    short = (
        max(
            math.hypot(AVOID_CLEAR_M + contact, lat),
            math.hypot(look_max + contact, lat),
            contact + 2.0 * vmax * params.step_s + 1e-6,
        )
        + 1e-6
    )
    return radius, short


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
        self.steps = 0
        self._obstacles: dict[int, tuple[float, float, float]] = {}
        self._next_obstacle = 1
        self._obst = np.zeros((0, 3))
        self._next_sample = clock.now() + TRAJECTORY_PERIOD_S
        self._samples_t: list[float] = []
        self._samples_xy: list[np.ndarray] = []
        self._samples_dropped = 0
        self._traj_start: list[tuple[float, float, float, int]] = []
        self._backends: dict[str, NamespacedBackend] = {}
        self._chargers = np.array([(c.x, c.y) for c in params.chargers], dtype=float).reshape(-1, 2)
        radius, short = pair_radii(params)
        self._pairs = NeighborPairs(radius, short, params.model.max_linear_speed)
        footprints = FootprintGrid(grid, self.planner.footprint, AVOID_CLEAR_M)
        avoidance = Avoidance(self.state, self._pairs, footprints, params.model.radius)
        self._follower = PathFollower(self.state, params, avoidance)
        self._safety = Safety(self.state, params, avoidance, footprints, self.planner)
        self._contacts = Contacts(self.state, params, self._pairs)
        self._dispatch = GoalDispatch(self.state, params, self.planner, clock, self._safety)

    # -- robots -----------------------------------------------------------------------

    @property
    def namespaces(self) -> list[str]:
        """Robot namespaces in the order they were added."""
        return [r.namespace for r in self._dispatch.order]

    @property
    def collisions(self) -> int:
        """Robot-robot contact events so far (a pair that starts touching counts once)."""
        return self._contacts.total

    @property
    def collision_events(self) -> list[tuple[float, str, str, float, float]]:
        """``(t, namespace_a, namespace_b, x, y)`` of the contact events, the last
        :data:`sim.history.EVENTS_KEPT` at least (the live list)."""
        return self._contacts.events

    def add_robot(self, spec: RobotSpec) -> None:
        """Add a robot at ``spec.start``. Raises :class:`BackendError` if the namespace is
        taken or the robot's footprint at the start overlaps a static obstacle or leaves the
        map. Robots may be placed touching each other (that counts as a collision event at the
        next step)."""
        ns = spec.namespace
        if ns in self._dispatch.robots:
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
        self._dispatch.add(Robot(spec.name, ns, i, self.state))
        self._traj_start.append((now, float(p.x), float(p.y), self._samples_dropped + len(self._samples_t)))

    def _robot(self, namespace: str) -> Robot:
        try:
            return self._dispatch.robots[namespace]
        except KeyError:
            raise BackendError(f"no robot with namespace {namespace!r} in the simulator") from None

    def robot_state(self, namespace: str) -> RobotState:
        """Current state of the robot ``namespace`` (pose always known in the sim)."""
        x, y, th, v, w, battery, charging, stuck, dist, collisions = self.state.row(
            self._robot(namespace).index
        )[:10]
        state: RobotState = make_robot_state(
            pose=Pose2D(x, y, th),
            linear_velocity=v,
            angular_velocity=w,
            battery=battery,
            charging=bool(charging),
            stuck=bool(stuck),
            distance_m=dist,
            collisions=int(collisions),
        )
        return state

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]]:
        """``(t, x, y)`` samples of the robot, one at its addition and then every
        :data:`TRAJECTORY_PERIOD_S` simulated seconds; those of the last
        :data:`sim.history.TRAJECTORY_KEEP_S` seconds at least are kept (a copy)."""
        i = self._robot(namespace).index
        t0, x0, y0, first = self._traj_start[i]
        first -= self._samples_dropped
        out = [(t0, x0, y0)] if first >= 0 else []
        first = max(first, 0)
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
        self._obstacles_changed()
        return oid

    def remove_obstacle(self, obstacle_id: int) -> None:
        """Remove a dynamic obstacle; unknown ids are ignored."""
        self._obstacles.pop(obstacle_id, None)
        self._obstacles_changed()

    def _obstacles_changed(self) -> None:
        self._obst = np.array(list(self._obstacles.values()), dtype=float).reshape(-1, 3)
        self._dispatch.obstacles = self._obst

    # -- goals ------------------------------------------------------------------------

    def send_goal(self, namespace: str, goal: object) -> str:
        """Start ``goal`` on robot ``namespace`` and return its fresh id at once.

        The goal is EXECUTING immediately, or already terminal if it was REJECTED (a
        NavigateThroughPoses without poses, a non-finite pose) or ABORTED at start (planning
        failure, an empty FollowWaypoints, invalid BackUp input, ...). A goal the robot was
        executing ends ABORTED with an error message naming the preempting goal. Raises
        :class:`BackendError` (changing nothing) for an unknown namespace or an object that is
        not a goal of :mod:`fleet.types`.
        """
        return self._dispatch.send(self._robot(namespace), goal)

    def goal_state(self, goal_id: str) -> GoalState:
        """Snapshot of goal ``goal_id`` (pure read). Raises ``KeyError`` for an id never issued."""
        return self._dispatch.goal_state(goal_id)

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id``: it ends CANCELED at once and the robot decelerates to a stop.
        A no-op for a finished or unknown goal."""
        self._dispatch.cancel(goal_id)

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
        dt = self.params.step_s
        now = self.clock.advance(dt)
        self.steps += 1
        s = self.state
        n = s.n
        if n == 0:
            return
        self._pairs.update(s.x[:n], s.y[:n], self.steps, dt)
        obst = self._obst
        vd = s.vd[:n]
        wd = s.wd[:n]
        vd[:] = 0.0
        wd[:] = 0.0
        # 1. commands: Python tasks (rare: Spin, BackUp, Wait, between waypoints) ...
        py_robots = self._dispatch.control(now, dt, vd, wd)
        # ... and the vectorized path follower for every robot driving along a path
        fol = np.flatnonzero(s.fol[:n])
        if fol.size:
            stopped, arrived = self._follower.follow(fol, now, obst)
            if stopped.size:
                self._dispatch.path_events(stopped, arrived, now)
        # 2. acceleration and speed limits, faults
        v, w = self._limits(vd, wd, dt)
        # 3. safety: be able to stop before whatever is ahead; refuse moves into obstacles
        self._safety.reactive_stop(v, dt, obst)
        ds, dth, moved = self._safety.move(v, w, dt, obst)
        self._dispatch.after_move(py_robots, ds, dth)
        # 4. battery and stuck detector
        self._battery(moved, w, np.abs(ds), dt)
        self._check_progress(now)
        # 5. contacts
        order = self._dispatch.order
        self._contacts.count(now, lambda i: order[i].namespace)
        self._sample(now)

    def _limits(self, vd: np.ndarray, wd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The commands ``vd``, ``wd`` within the acceleration and speed limits; zero for a
        stalled robot or an empty battery."""
        s = self.state
        n = vd.size
        m = self.params.model
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
        return v, w

    def _battery(self, moved: np.ndarray, w: np.ndarray, adist: np.ndarray, dt: float) -> None:
        """Drain by the distance ``adist`` (m) driven and the time; charge robots that stand
        still (no move, no turn) within ``charger_radius`` of a charger."""
        s = self.state
        n = moved.size
        charging = np.zeros(n, dtype=bool)
        if self._chargers.shape[0]:
            idle = np.flatnonzero(~moved & (w == 0.0))
            if idle.size:
                x, y = s.x[:n], s.y[:n]
                cx = self._chargers[:, 0]
                cy = self._chargers[:, 1]
                near = np.hypot(cx[None, :] - x[idle, None], cy[None, :] - y[idle, None])
                charging[idle] = (near <= self.params.charger_radius).any(axis=1)
        s.battery[:n] = self.params.battery.integrate(s.battery[:n], adist, dt, charging)
        s.charging[:n] = charging

    def _check_progress(self, now: float) -> None:
        """The progress checker: a robot whose task wants it to translate but that stayed
        within :data:`PROGRESS_RADIUS_M` for ``stuck_time_s`` is stuck."""
        s = self.state
        n = s.n
        x, y = s.x[:n], s.y[:n]
        px, py, pt = s.px[:n], s.py[:n], s.pt[:n]
        far = np.hypot(x - px, y - py) > PROGRESS_RADIUS_M
        if far.any():
            np.copyto(px, x, where=far)
            np.copyto(py, y, where=far)
            pt[far] = now
            s.stuck[:n][far] = False
        near_p = ~far
        # a path follower wants to move until it stands at its final position, also while it
        # turns in place to get round something in its way
        trying = s.has_task[:n] & (s.drives[:n] | (s.fol[:n] & ~s.f_xy[:n]))
        pt[near_p & ~trying] = now
        stuck = np.flatnonzero(near_p & trying & (now - pt >= self.params.stuck_time_s - 1e-9))
        for i in stuck.tolist():
            self._dispatch.stuck(i, now)

    def _sample(self, now: float) -> None:
        if now >= self._next_sample - 1e-9:
            n = self.state.n
            self._samples_t.append(now)
            self._samples_xy.append(np.stack((self.state.x[:n], self.state.y[:n]), axis=1))
            while self._next_sample <= now + 1e-9:
                self._next_sample += TRAJECTORY_PERIOD_S
            keep = int(TRAJECTORY_KEEP_S / TRAJECTORY_PERIOD_S)
            trim_oldest(self._samples_xy, keep)
            self._samples_dropped += trim_oldest(self._samples_t, keep)
