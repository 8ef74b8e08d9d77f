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
from collections.abc import Callable, Sequence

import numpy as np

from fleet.clock import SimClock, step_until
from fleet.errors import BackendError
from fleet.maps import OccupancyGrid
from fleet.navigation import NavBatch
from fleet.robots import RobotSpec, SimParams
from fleet.types import ErrorCode, GoalState, Pose2D, RobotState, make_pose, normalize_angle
from sim import kernels
from sim.avoidance import AVOID_CLEAR_M, AVOID_LOOKAHEAD_M, CORRIDOR_MARGIN_M, Avoidance
from sim.backend import NamespacedBackend
from sim.batch import SimBatch
from sim.costmap import CostmapRaster, Costmaps, Layer, Mark
from sim.dispatch import GoalDispatch
from sim.follower import PathFollower
from sim.footprint import FootprintGrid
from sim.history import EVENTS_KEPT, TRAJECTORY_KEEP_S, trim_oldest
from sim.localization import Localization, LocalizationState
from sim.planner import GridPlanner, PlanResult
from sim.robot import Robot
from sim.safety import STOP_GAP_M, Contacts, Safety
from sim.snapshots import GoalTable, RobotTable, localized_robot_state, make_robot_state
from sim.spatial import NeighborPairs
from sim.state import FleetState
from sim.upkeep import Upkeep

#: Trajectories are sampled every this many simulated seconds.
TRAJECTORY_PERIOD_S = 0.5
#: Fault names accepted by :meth:`Simulator.set_fault`.
FAULTS = ("stalled", "localization_lost", "navigation_down")
#: Why the safety watchdog stops a robot, by cause.
SAFETY_REASONS = {
    "localization_lost": "localization lost",
    "navigation_down": "navigation server down",
    "mislocalized": "not localized",
}


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
        compiled: the step's loops compiled or NumPy (default :func:`sim.kernels.enabled`): same bits.
    """

    def __init__(
        self, grid: OccupancyGrid, params: SimParams, clock: SimClock, *, compiled: bool | None = None
    ) -> None:
        if params.step_s <= 0:
            raise BackendError(f"SimParams.step_s must be positive, got {params.step_s}")
        self.grid = grid
        self.params = params
        self.clock = clock
        self.compiled = kernels.enabled() if compiled is None else compiled and kernels.ready()
        self.planner = GridPlanner(grid, params.model.radius, compiled=self.compiled)
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
        self._pairs = NeighborPairs(radius, short, params.model.max_linear_speed, self.compiled)
        footprints = FootprintGrid(grid, self.planner.footprint, AVOID_CLEAR_M)
        avoidance = Avoidance(self.state, self._pairs, footprints, params.model.radius, self.compiled)
        self._follower = PathFollower(self.state, params, avoidance, self.compiled)
        self._safety = Safety(self.state, params, avoidance, footprints, self.planner)
        self._contacts = Contacts(self.state, params, self._pairs, self.compiled)
        self._upkeep = Upkeep(self.state, params, self._chargers, self.compiled)
        self.costmaps = Costmaps(grid, params.model.radius, self.compiled)
        self.localization = Localization()
        self._dispatch = GoalDispatch(self.state, params, self.planner, clock, self._safety, self.costmaps)
        self._batch = SimBatch(self.state, self.localization, self._dispatch, self.robot_state, self.compiled)
        #: Why each robot is stopped by the safety watchdog (absent: it is not).
        self.safety_stops: dict[str, str] = {}
        #: ``(t, namespace, reason)`` of every safety stop, the last :data:`sim.history.EVENTS_KEPT`.
        self.safety_events: list[tuple[float, str, str]] = []

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
        self.localization.add(Pose2D(float(p.x), float(p.y), normalize_angle(float(p.theta))), now)
        self.costmaps.add(ns, float(p.x), float(p.y), now)
        self._traj_start.append((now, float(p.x), float(p.y), self._samples_dropped + len(self._samples_t)))

    def _robot(self, namespace: str) -> Robot:
        try:
            return self._dispatch.robots[namespace]
        except KeyError:
            raise BackendError(f"no robot with namespace {namespace!r} in the simulator") from None

    def robot_state(self, namespace: str) -> RobotState:
        """Current state of the robot ``namespace``: ``pose`` is its localization estimate (the
        true pose while it is localized); ``localized``, ``pose_age_s``, ``navigation_ready``
        and ``safety_stop`` come from :mod:`sim.localization` and the faults."""
        r = self._robot(namespace)
        x, y, th, v, w, battery, charging, stuck, dist, collisions = self.state.row(r.index)[:10]
        est = self.localization.robots[r.index]
        pose = make_pose(x, y, th)
        if not est.localized or est.lost:
            loc = self.localization.state(r.index, pose, self.clock.now())
            state_loc: RobotState = make_robot_state(
                pose=loc.pose,
                linear_velocity=v,
                angular_velocity=w,
                battery=battery,
                charging=bool(charging),
                stuck=bool(stuck),
                distance_m=dist,
                collisions=int(collisions),
                localized=False,
                pose_age_s=max(0.0, self.clock.now() - loc.updated),
                navigation_ready=r.fault != "navigation_down",
                safety_stop=self.safety_stops.get(namespace, ""),
            )
            return state_loc
        return localized_robot_state(
            pose,
            v,
            w,
            battery,
            bool(charging),
            bool(stuck),
            dist,
            int(collisions),
            r.fault != "navigation_down",
            self.safety_stops.get(namespace, "") if self.safety_stops else "",
        )

    def true_pose(self, namespace: str) -> Pose2D:
        """Where the robot truly is (``map``), whatever its localization believes."""
        return self._robot(namespace).pose

    def followed_path(self, namespace: str) -> tuple[tuple[float, float], ...] | None:
        """The path (``map``, m) the robot's navigation goal is following now: the planned
        path from where the goal started through its poses; ``None`` when it follows none."""
        i = self._robot(namespace).index
        s = self.state
        if not s.fol[i]:
            return None
        o, k = int(s.f_off[i]), int(s.f_len[i])
        return tuple(zip(s.pts_x[o : o + k].tolist(), s.pts_y[o : o + k].tolist(), strict=True))

    def localization_state(self, namespace: str) -> LocalizationState:
        """The robot's odometry, estimated ``map -> odom`` and estimate now
        (:class:`sim.localization.LocalizationState`)."""
        r = self._robot(namespace)
        return self.localization.state(r.index, r.pose, self.clock.now())

    def set_initial_pose(self, namespace: str, pose: Pose2D) -> bool:
        """An initial pose estimate for the robot (``initialpose``): returns whether the
        localizer converged (the hint was within about 1 m and 0.6 rad of the true pose);
        otherwise the hint becomes the robot's (wrong) estimate, it is not localized and the
        safety watchdog stops it until it is localized again."""
        r = self._robot(namespace)
        ok = self.localization.initial_pose(r.index, pose, r.pose, self.clock.now())
        self._update_safety(r)
        return ok

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

    def fault_of(self, namespace: str) -> str | None:
        """The fault injected into the robot ``namespace`` (``None``: none)."""
        return self._robot(namespace).fault

    def set_fault(self, namespace: str, fault: str | None) -> None:
        """Inject a fault (one at a time; ``None`` clears it):

        * ``"stalled"``: the wheels stop responding (the robot stops at once and cannot move
          or turn);
        * ``"localization_lost"``: the localizer stops confirming the robot's estimate
          (``RobotState.localized`` false, ``pose_age_s`` grows); clearing it re-localizes;
        * ``"navigation_down"``: the robot's navigation server is down
          (``RobotState.navigation_ready`` false); new goals are aborted.

        The last two trip the safety watchdog: the robot is commanded to stop at the next step
        (one control period) and its running goal ends ABORTED with
        ``ErrorCode.SAFETY_STOPPED``; it stays stopped until the fault is cleared.
        """
        if fault is not None and fault not in FAULTS:
            raise BackendError(f"unknown fault {fault!r}; known faults: {', '.join(FAULTS)}")
        r = self._robot(namespace)
        r.fault = fault
        if fault == "navigation_down":
            self._batch.navigation_down.add(r.index)
        else:
            self._batch.navigation_down.discard(r.index)
        self.state.stalled[r.index] = fault == "stalled"
        self.localization.set_lost(r.index, fault == "localization_lost", self.clock.now())
        self._update_safety(r)

    def _update_safety(self, r: Robot) -> None:
        """The safety watchdog's verdict for ``r``: stop it (and abort its running goal) when
        its localization is lost or not converged or its navigation server is down."""
        est = self.localization.robots[r.index]
        if r.fault == "navigation_down":
            reason = SAFETY_REASONS["navigation_down"]
        elif est.lost:
            reason = SAFETY_REASONS["localization_lost"]
        elif not est.localized:
            reason = f"{SAFETY_REASONS['mislocalized']}: {est.reason}"
        else:
            reason = ""
        ns = r.namespace
        was = self.safety_stops.get(ns, "")
        self.state.halt[r.index] = bool(reason)
        if not reason:
            self.safety_stops.pop(ns, None)
            return
        self.safety_stops[ns] = reason
        if reason != was:
            self.safety_events.append((self.clock.now(), ns, reason))
            trim_oldest(self.safety_events, EVENTS_KEPT)
        self._stop_goal(r, reason)

    def _stop_goal(self, r: Robot, reason: str) -> None:
        """Abort ``r``'s running goal (a Wait may go on: it does not move the robot)."""
        if self._dispatch.running_kind(r) not in (None, "wait"):
            code = ErrorCode.SERVER_UNAVAILABLE if r.fault == "navigation_down" else ErrorCode.SAFETY_STOPPED
            self._dispatch.abort_running(r, code, f"Safety stop: {reason}.")

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

    # -- costmaps ----------------------------------------------------------------------

    def plan(
        self, namespace: str, start: tuple[float, float], goal: tuple[float, float], *, strict: bool = True
    ) -> PlanResult:
        """Plan ``start`` -> ``goal`` (m, ``map``) for the robot on its global costmap (the
        static map and the obstacles it has learned; see :mod:`sim.costmap`). ``strict``
        (default, what Nav2's planner server does): ``NO_VALID_PATH`` when learned obstacles
        close every way; otherwise the static plan then (what the simulator's own navigation
        goals drive)."""
        return self._dispatch.plan(self._robot(namespace), start, goal, strict)

    def clear_costmaps(self, namespace: str, which: Layer | str = Layer.BOTH) -> int:
        """Clear the robot's learned obstacles in ``which`` costmap (``global``, ``local`` or
        ``both``; the static map stays). Returns the marks removed. What Nav2's
        ``clear_entirely_*`` services and the ClearCostmap recovery do."""
        return self.costmaps.clear(self._robot(namespace).index, which)

    def clear_costmap_region(
        self,
        namespace: str,
        which: Layer | str,
        reset_distance: float,
        *,
        center: Pose2D | None = None,
        keep_inside: bool = False,
    ) -> int:
        """Clear the robot's learned obstacles in the square of side ``reset_distance`` (m)
        around ``center`` (default: the robot), or, with ``keep_inside``, everywhere but
        there (Nav2's ``clear_around_*``, ``clear_around_pose_*`` and ``clear_except_*``).
        Returns the marks removed."""
        r = self._robot(namespace)
        c = center if center is not None else r.pose
        return self.costmaps.clear_region(r.index, which, c.x, c.y, reset_distance, inside=not keep_inside)

    def costmap_marks(self, namespace: str, which: Layer | str = Layer.GLOBAL) -> list[Mark]:
        """The obstacles the robot has learned in ``which`` costmap (copies of the marks)."""
        marks = self.costmaps.marks(self._robot(namespace).index, which)
        return [Mark(m.x, m.y, m.r, m.seen, m.source) for m in marks]

    def costmap(
        self, namespace: str, which: Layer | str = Layer.GLOBAL, layer: str = "master"
    ) -> CostmapRaster:
        """The robot's ``which`` costmap (``global`` or ``local``) as Nav2 cost values
        (:meth:`sim.costmap.Costmaps.raster`)."""
        r = self._robot(namespace)
        return self.costmaps.raster(r.index, which, r.x, r.y, layer)

    def _obstacles_changed(self) -> None:
        self._obst = np.array(list(self._obstacles.values()), dtype=float).reshape(-1, 3)
        self._dispatch.obstacles = self._obst

    # -- goals ------------------------------------------------------------------------

    def send_goal(self, namespace: str, goal: object) -> str:
        """Start ``goal`` on robot ``namespace`` and return its fresh id at once.

        The goal is EXECUTING immediately, or already terminal if it was REJECTED (a
        NavigateThroughPoses without poses, a non-finite pose) or ABORTED at start (planning
        failure, an empty FollowWaypoints, invalid BackUp input, ...). A goal the robot was
        executing ends ABORTED with an error message naming the preempting goal. While the
        safety watchdog stops the robot (:meth:`set_fault`) a goal that moves it ends ABORTED
        at once (``SAFETY_STOPPED``; ``SERVER_UNAVAILABLE`` with its navigation down). Raises
        :class:`BackendError` (changing nothing) for an unknown namespace or an object that is
        not a goal of :mod:`fleet.types`.
        """
        r = self._robot(namespace)
        gid = self._dispatch.send(r, goal)
        reason = self.safety_stops.get(namespace) if self.safety_stops else None
        if reason is not None:
            self._stop_goal(r, reason)
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        """Snapshot of goal ``goal_id`` (pure read). Raises ``KeyError`` for an id never issued."""
        return self._dispatch.goal_state(goal_id)

    def query_batch(self, namespaces: Sequence[str], goal_ids: Sequence[str | None]) -> NavBatch:
        """Robot and goal states of many robots as arrays (:mod:`sim.batch`; pure read)."""
        return self._batch.query_batch(namespaces, goal_ids)

    def goal_table(self) -> GoalTable:
        """Every robot's latest motion goal number and status as arrays (:class:`GoalTable`):
        polling a whole fleet in one call, no snapshot object built (:mod:`sim.batch`)."""
        return self._batch.goal_table()

    def robot_table(self) -> RobotTable:
        """Every robot's true state as arrays (:class:`RobotTable`), in one call."""
        return self._batch.robot_table()

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id``: it ends CANCELED at once and the robot decelerates to a stop.
        A no-op for a finished or unknown goal."""
        self._dispatch.cancel(goal_id)

    def cancel_all(self) -> int:
        """Cancel every running goal of every robot (as :meth:`cancel_goal`); returns how many."""
        live = [t.record.goal_id for t in list(self._dispatch.tasks.values()) if not t.done]
        for gid in live:
            self._dispatch.cancel(gid)
        return len(live)

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
        # 2. speed limits, faults; 3. safety: stop before what is ahead, not into obstacles
        if self.compiled and not obst.size:
            w, ds, dth, moved = self._safety.limit_stop_move(vd, wd, dt)
        else:
            v, w = self._limits(vd, wd, dt)
            self._safety.reactive_stop(v, dt, obst)
            ds, dth, moved = self._safety.move(v, w, dt, obst)
        self._dispatch.after_move(py_robots, ds, dth)
        # 4. battery and stuck detector
        for i in self._upkeep.update(moved, w, ds, dt, now).tolist():
            self._dispatch.stuck(i, now)
        # 5. contacts
        order = self._dispatch.order
        self._contacts.count(now, lambda i: order[i].namespace)
        self.costmaps.sense(now, s.x[:n], s.y[:n], self._obstacles)
        self._sample(now)

    def _limits(self, vd: np.ndarray, wd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``vd``, ``wd`` within the acceleration and speed limits; 0 when stalled or flat."""
        s = self.state
        n = vd.size
        m = self.params.model
        dv, dw = m.max_linear_accel * dt, m.max_angular_accel * dt
        v0, w0 = s.v[:n], s.w[:n]
        v = np.maximum(vd, v0 - dv)
        np.minimum(v, v0 + dv, out=v)
        np.maximum(v, -m.max_linear_speed, out=v)
        np.minimum(v, m.max_linear_speed, out=v)
        w = np.maximum(wd, w0 - dw)
        np.minimum(w, w0 + dw, out=w)
        np.maximum(w, -m.max_angular_speed, out=w)
        np.minimum(w, m.max_angular_speed, out=w)
        dead = s.stalled[:n] | s.halt[:n] | (s.battery[:n] <= 0.0)
        if dead.any():
            v[dead] = 0.0
            w[dead] = 0.0
        return v, w

    def _sample(self, now: float) -> None:
        if now >= self._next_sample - 1e-9:
            n = self.state.n
            self._samples_t.append(now)
            # float32: well under a millimetre on any warehouse map, half the memory
            self._samples_xy.append(np.stack((self.state.x[:n], self.state.y[:n]), axis=1).astype(np.float32))
            while self._next_sample <= now + 1e-9:
                self._next_sample += TRAJECTORY_PERIOD_S
            keep = int(TRAJECTORY_KEEP_S / TRAJECTORY_PERIOD_S)
            trim_oldest(self._samples_xy, keep)
            self._samples_dropped += trim_oldest(self._samples_t, keep)
