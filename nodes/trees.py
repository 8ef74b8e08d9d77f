"""Functions that build the robots' behavior trees (py_trees idiom: a function returns a
subtree; trees are composed from subtrees).

* :func:`battery_guard`: ``BatteryLow -> NavigateToPose(charger) -> Charge``.
* :func:`patrol_branch`: loop the blackboard ``route`` with :class:`FollowRoute`, under a
  :class:`~nodes.recovery.RecoveryNode`, restarted when ``task_id`` changes.
* :func:`pick_branch`: shelf -> dwell -> drop -> mark done, for the blackboard ``pick``.
* :func:`patrol_tree`, :func:`picking_tree`, :func:`build_tree`: whole per-robot trees.
* :func:`dump_tree`: an ASCII / unicode drawing of a tree.

Every tree reads and writes only its robot's blackboard namespace (``nodes.blackboard``)
and talks to the robot only through its :class:`~fleet.navigation.NavigationBackend`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt
import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from fleet.errors import FleetError
from fleet.navigation import Clock, NavigationBackend
from fleet.robots import BatteryModel
from fleet.traffic.purpose import CHARGE_REACH_M, Purpose
from fleet.types import Goal, GoalState, Mode, NavigateThroughPoses, NavigateToPose, Pose2D, TreeKind
from fleet.wake import Wake
from nodes.blackboard import normalize_namespace, read_key, robot_blackboard
from nodes.conditions import BatteryLow, HasAssignment
from nodes.leaves import (
    Charge,
    CompletePick,
    Idle,
    NavigateThroughPosesAction,
    NavigateToPoseAction,
    WaitAction,
)
from nodes.recovery import RecoveryNode, RestartOnChange, recovery_actions
from nodes.traffic import FollowGrant


def next_route_index(route: Sequence[Pose2D], pose: Pose2D | None, tolerance_m: float = 0.3) -> int:
    """Index of the route pose a robot at ``pose`` should drive to next.

    The nearest pose, unless the robot already stands on it (within ``tolerance_m``) or
    has passed it along the segment to the following pose, in which case the following one.
    ``0`` when the pose is unknown or the route has one pose.
    """
    n = len(route)
    if pose is None or n <= 1:
        return 0
    i = min(range(n), key=lambda k: pose.distance_to(route[k]))
    nxt = route[(i + 1) % n]
    if pose.distance_to(route[i]) <= tolerance_m or pose.distance_to(nxt) < route[i].distance_to(nxt):
        return (i + 1) % n
    return i


class FollowRoute(NavigateThroughPosesAction):
    """One lap of the robot's patrol route (blackboard ``route``), driven with navigation
    goals sent one after the other.

    Goals: the lap is the route's ``n`` poses rotated to start at :func:`next_route_index`
    of the robot's pose ``k`` (so it resumes near the robot after an interruption:
    charging, recovery, a new route). A lap ends where it started, and a navigator treats a
    goal that ends at the robot's own position as reached at once (Nav2's goal checker does
    the same); so the lap is sent as two legs, ``NavigateThroughPoses(lap[:m])`` then
    ``NavigateThroughPoses(lap[m:])`` with ``m = ceil(n / 2)``. When the robot does not
    stand on the pose before ``route[k]`` (it is joining the route rather than continuing
    the previous lap), an approach ``NavigateToPose(route[k])`` comes first, so the robot
    joins the route facing along it, and the two legs split the rest of the lap. A route
    needs at least two distinct poses.

    Blackboard: on start, if ``task_id`` differs from ``lap_task_id`` the lap counter is
    restarted (``laps = 0``, ``lap_task_id = task_id``); ``mode = Mode.PATROL``;
    ``route_progress`` follows the feedback (lap poses done plus the driven fraction of the
    current goal, over ``n``); when the last leg succeeds
    ``laps += 1`` and ``route_progress = 1``.

    Returns RUNNING (a goal is executing, or one just succeeded and the next was sent),
    SUCCESS (the lap is done), FAILURE (no route, a goal failed: ``feedback_message`` has
    the error code and message). Cancel: like every :class:`~nodes.leaves.GoalAction`,
    ``terminate(INVALID)`` while RUNNING cancels the executing goal. Loop it with a
    ``Repeat`` decorator.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self, backend: NavigationBackend, *, name: str = "FollowRoute", tolerance_m: float = 0.3
    ) -> None:
        super().__init__(backend, read_key(backend.namespace, "route"), name=name, mode=Mode.PATROL)
        self.tolerance_m = tolerance_m
        self.route_bb = robot_blackboard(
            backend.namespace,
            name=f"{name}-route",
            keys=("route", "task_id", "laps", "lap_task_id", "route_progress"),
        )
        self.blackboards.append(self.route_bb)
        #: Index into the route of the first pose of the current lap.
        self.start_index = 0
        #: The goals of the current lap (approach, then the two legs).
        self.legs: list[Goal] = []
        #: Index into :attr:`legs` of the executing goal.
        self.leg = 0
        self._leg_poses: list[int] = []
        self._lap_poses = 0
        self._leg_length = 0.0

    def make_goal(self) -> Goal | None:
        bb = self.route_bb
        if bb.task_id != bb.lap_task_id:
            bb.laps = 0
            bb.lap_task_id = bb.task_id
        route = tuple(bb.route or ())
        self.legs, self._leg_poses, self.leg = [], [], 0
        if not route:
            return None
        here = self.backend.robot_state().pose
        k = next_route_index(route, here, self.tolerance_m)
        self.start_index = k
        lap = route[k:] + route[:k]
        rest = lap
        if len(route) > 1 and (here is None or here.distance_to(route[k - 1]) > self.tolerance_m):
            self.legs.append(NavigateToPose(lap[0]))
            self._leg_poses.append(1)
            rest = lap[1:]
        m = (len(rest) + 1) // 2
        for leg in (rest[:m], rest[m:]) if len(rest) > 1 else (rest,):
            self.legs.append(NavigateThroughPoses(leg))
            self._leg_poses.append(len(leg))
        self._lap_poses = len(lap)
        self._leg_length = 0.0
        bb.route_progress = 0.0
        return self.legs[0]

    def on_state(self, state: GoalState) -> None:
        if not self.legs:
            return
        leg_poses = self._leg_poses[self.leg]
        done_before = sum(self._leg_poses[: self.leg])
        fb = state.feedback
        frac = 0.0
        if fb.distance_remaining_m is not None:
            self._leg_length = max(self._leg_length, fb.distance_remaining_m)
            if self._leg_length > 0.0:
                frac = 1.0 - fb.distance_remaining_m / self._leg_length
        elif fb.number_of_poses_remaining is not None and leg_poses:
            frac = 1.0 - fb.number_of_poses_remaining / leg_poses
        progress = (done_before + min(1.0, max(0.0, frac)) * leg_poses) / max(1, self._lap_poses)
        self.route_bb.route_progress = min(1.0, max(0.0, progress))

    def on_success(self, state: GoalState) -> Status:
        if self.leg + 1 < len(self.legs):
            self.leg += 1
            self._leg_length = 0.0
            self.send(self.legs[self.leg])
            return Status.RUNNING
        bb = self.route_bb
        bb.laps = int(bb.laps) + 1
        bb.route_progress = 1.0
        self.feedback_message = f"lap {bb.laps} done ({self.goal_id})"
        return Status.SUCCESS


def navigate_with_recovery(
    action: Behaviour, backend: NavigationBackend, *, retries: int = 6, name: str | None = None
) -> RecoveryNode:
    """``RecoveryNode(action, recovery_actions(backend), retries)``: the Nav2-style wrapper
    of a navigation leaf."""
    return RecoveryNode(action, recovery_actions(backend), retries, name=name or f"{action.name}Recovery")


def battery_guard(
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    go_to_charger: Behaviour | None = None,
) -> Behaviour:
    """The highest-priority branch of every robot tree.

    ``Sequence[BatteryLow(low, resume), HasCharger, Sequence(memory)[Recovery(
    NavigateToPose(charger)), Charge(resume)]]``. The charger pose is read from the
    blackboard ``charger`` when the leaf starts; ``go_to_charger`` replaces the
    recovery-wrapped ``NavigateToPose`` (the traffic tree drives its grant to a charger).
    RUNNING while going to / standing on the
    charger, SUCCESS when charged to ``battery.resume``, FAILURE when the battery is fine or
    no charger is assigned (the robot then carries on with its work), or when the charger
    cannot be reached after every recovery or the robot does not charge there.
    """
    if go_to_charger is None:
        go_to_charger = navigate_with_recovery(
            NavigateToPoseAction(
                backend, read_key(namespace, "charger"), name="GoToCharger", mode=Mode.CHARGING
            ),
            backend,
        )
    go_charge = py_trees.composites.Sequence(
        "GoCharge", memory=True, children=[go_to_charger, Charge(backend, clock, battery.resume)]
    )
    return py_trees.composites.Sequence(
        "BatteryGuard",
        memory=False,
        children=[
            BatteryLow(
                backend, battery.low, battery.resume, threshold=charge_threshold(namespace, backend, battery)
            ),
            HasAssignment(namespace, "charger", name="HasCharger"),
            go_charge,
        ],
    )


_Sites = tuple[tuple[Pose2D, ...], npt.NDArray[np.float64], npt.NDArray[np.float64]]
#: The coordinates of the charger sites asked about, by identity (a fleet's agents share one).
_site_cache: dict[int, _Sites] = {}


def _site_arrays(sites: tuple[Pose2D, ...]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``(xs, ys)`` of ``sites`` (m, map frame), built once per sequence."""
    got = _site_cache.get(id(sites))
    if got is None or got[0] is not sites:
        if len(_site_cache) > 64:
            _site_cache.clear()
        got = _site_cache[id(sites)] = (
            sites,
            np.array([s.x for s in sites], dtype=float),
            np.array([s.y for s in sites], dtype=float),
        )
    return got[1], got[2]


class ChargeThreshold:
    """The battery guard's energy-based trigger (also the XML ``BatteryLow`` without a ``low``
    port). ``() -> float``: :meth:`BatteryModel.charge_threshold` of the Manhattan distance (m)
    from the robot to its charger (blackboard ``charger``); ``battery.low`` when either is
    unknown.

    With blackboard ``charger_sites`` (a traffic-managed robot: its policy sends it to a free
    charger at most :data:`~fleet.traffic.purpose.CHARGE_REACH_M` farther than its nearest
    one, not to the named one), a robot so far from its named charger that the threshold
    would reach ``resume`` (on its way to work across the floor: it would go to charge again
    as soon as it has charged, for as long as it stays far) measures to the nearest site
    plus ``CHARGE_REACH_M`` instead, if that is nearer. Nearer its named charger nothing
    changes."""

    def __init__(self, namespace: str, backend: NavigationBackend, battery: BatteryModel) -> None:
        self._charger = read_key(namespace, "charger")
        self._sites = read_key(namespace, "charger_sites")
        self.backend = backend
        self.battery = battery

    def __call__(self) -> float:
        p = self.backend.robot_state().pose
        measured = self._measure(p)
        if measured is None:
            return self.battery.low
        d, _, _ = measured
        return self.battery.charge_threshold(d)

    def _measure(self, p: Pose2D | None) -> tuple[float, Pose2D, float] | None:
        """``(distance, charger, slack)`` the threshold is measured with from ``p``: distance =
        Manhattan distance to ``charger`` plus ``slack`` (m); ``None`` without a charger or
        a pose."""
        c = self._charger()
        if not isinstance(c, Pose2D) or p is None:
            return None
        best = (abs(c.x - p.x) + abs(c.y - p.y), c, 0.0)
        sites = self._sites()
        if sites and self.battery.charge_threshold(best[0]) >= self.battery.resume:
            xs, ys = _site_arrays(sites)
            dist = np.abs(xs - p.x) + np.abs(ys - p.y)
            i = int(np.argmin(dist))
            near = float(dist[i]) + CHARGE_REACH_M
            if near < best[0]:
                best = (near, sites[i], CHARGE_REACH_M)
        return best

    def declare(self, wake: Wake, cap: float) -> None:
        """Tick when the battery falls below ``min(cap, this threshold)`` (:mod:`fleet.wake`):
        the named charger's line; every tick while the robot measures to the nearest site
        (far from its named charger; the threshold is not one line there)."""
        measured = self._measure(self.backend.robot_state().pose)
        if measured is None:
            c = self._charger()
            if isinstance(c, Pose2D):  # no pose yet: the named charger's line
                a, b = self.battery.charge_line()
                wake.battery_below_line(self.battery.low, cap, a, b, (c.x, c.y))
                return
            wake.battery_below(min(cap, self.battery.low))
            return
        _, c, slack = measured
        if slack:
            wake.every_tick()
            return
        a, b = self.battery.charge_line()
        wake.battery_below_line(self.battery.low, cap, a, b, (c.x, c.y))


def charge_threshold(namespace: str, backend: NavigationBackend, battery: BatteryModel) -> ChargeThreshold:
    """The battery guard's trigger of robot ``namespace`` (:class:`ChargeThreshold`)."""
    return ChargeThreshold(namespace, backend, battery)


def _task_watch(namespace: str, key: str) -> Callable[[], object]:
    """``() -> (task_id, <key>)`` of robot ``namespace``: what a branch restarts on."""
    task_id = read_key(namespace, "task_id")
    value = read_key(namespace, key)
    return lambda: (task_id(), value())


def patrol_branch(namespace: str, backend: NavigationBackend, *, retries: int = 6) -> Behaviour:
    """``Sequence[HasRoute, RestartOnChange(task_id, route)[Repeat(-1)[Recovery(FollowRoute)]]]``.

    RUNNING while a route is assigned (laps repeat forever); FAILURE when there is no route
    or a lap fails after every recovery. A new ``task_id`` (or route) interrupts the running
    lap (its goal is canceled) and starts the new route at once; laps restart at 0.
    """
    laps = py_trees.decorators.Repeat(
        "Laps", navigate_with_recovery(FollowRoute(backend), backend, retries=retries), num_success=-1
    )
    return py_trees.composites.Sequence(
        "Patrol",
        memory=False,
        children=[
            HasAssignment(namespace, "route", name="HasRoute"),
            RestartOnChange("OnNewTask", laps, _task_watch(namespace, "route")),
        ],
    )


def pick_branch(namespace: str, backend: NavigationBackend, *, retries: int = 6) -> Behaviour:
    """``Sequence[HasPick, RestartOnChange(task_id, pick)[Sequence(memory)[Recovery(
    NavigateToPose(shelf)), Wait(dwell_s), Recovery(NavigateToPose(drop)), CompletePick]]]``.

    Shelf, dwell and drop are read from the blackboard ``pick`` when each leaf starts.
    RUNNING while picking, SUCCESS once the pick is done (``picks_done += 1``, ``pick`` is
    cleared), FAILURE when there is no pick or a step fails after every recovery. An
    interrupted pick (battery guard, new task) starts again from the shelf.
    """
    pick = read_key(namespace, "pick")

    def shelf() -> Pose2D | None:
        p = pick()
        return None if p is None else p.shelf

    def drop() -> Pose2D | None:
        p = pick()
        return None if p is None else p.drop

    def dwell() -> float | None:
        p = pick()
        return None if p is None else float(p.dwell_s)

    steps = py_trees.composites.Sequence(
        "PickSteps",
        memory=True,
        children=[
            navigate_with_recovery(
                NavigateToPoseAction(backend, shelf, name="GoToShelf", mode=Mode.PICKING),
                backend,
                retries=retries,
            ),
            WaitAction(backend, dwell, name="Dwell", mode=Mode.PICKING),
            navigate_with_recovery(
                NavigateToPoseAction(backend, drop, name="GoToDrop", mode=Mode.PICKING),
                backend,
                retries=retries,
            ),
            CompletePick(namespace),
        ],
    )
    return py_trees.composites.Sequence(
        "Picking",
        memory=False,
        children=[
            HasAssignment(namespace, "pick", name="HasPick"),
            RestartOnChange("OnNewPick", steps, _task_watch(namespace, "pick")),
        ],
    )


def patrol_tree(
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    *,
    retries: int = 6,
    traffic: bool = False,
) -> Behaviour:
    """The patrol robot's tree: ``Selector(memory=False)[battery_guard, patrol_branch, Idle]``.

    Priorities are re-checked every tick: a low battery interrupts the patrol (its goal ends
    CANCELED), the robot charges to ``battery.resume`` and resumes the route near where it
    is. Without a route the robot idles (``mode = Mode.IDLE``). Blackboard keys: see
    :mod:`nodes.blackboard`; ``namespace`` is the robot's (``/robot1``) and should equal
    ``backend.namespace``. With ``traffic=True`` the tree is :func:`traffic_patrol_tree`.
    """
    ns = normalize_namespace(namespace)
    if traffic:
        return traffic_patrol_tree(ns, backend, clock, battery)
    return _robot_tree(
        "PatrolRobot", ns, backend, clock, battery, patrol_branch(ns, backend, retries=retries)
    )


def traffic_patrol_tree(
    namespace: str, backend: NavigationBackend, clock: Clock, battery: BatteryModel
) -> Behaviour:
    """The patrol robot's tree under traffic management (``docs/traffic.md``)::

        Selector(memory=False)
          BatteryGuard: Sequence[BatteryLow, HasCharger,
                                 Sequence(memory)[FollowGrant(purpose=charge), Charge]]
          Patrol:       Sequence[HasRoute, FollowGrant(mode=patrol, count_laps)]
          FollowGrant(mode=idle)

    The tree decides only what the robot wants (its ``mode``: charging, patrol, idle); the
    coordinator's traffic policy turns that into a path (a charger, the patrol loop, a
    parking spot) and every branch drives only the granted part of it, so even an idle
    robot moves aside when the manager asks. No recovery behaviours: backing up or spinning
    would leave the reserved space; a failed goal is simply sent again.
    """
    ns = normalize_namespace(namespace)
    robot_blackboard(ns, name=f"{ns}-tree")
    to_charger = FollowGrant(
        backend, clock, mode=Mode.CHARGING, purpose=Purpose.CHARGE, name="GrantToCharger"
    )
    guard = battery_guard(ns, backend, clock, battery, go_to_charger=to_charger)
    patrol = py_trees.composites.Sequence(
        "Patrol",
        memory=False,
        children=[
            HasAssignment(ns, "route", name="HasRoute"),
            FollowGrant(backend, clock, mode=Mode.PATROL, count_laps=True, name="GrantPatrol"),
        ],
    )
    idle = FollowGrant(backend, clock, mode=Mode.IDLE, name="GrantIdle")
    return py_trees.composites.Selector(
        f"TrafficPatrolRobot {ns}", memory=False, children=[guard, patrol, idle]
    )


def picking_tree(
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    *,
    retries: int = 6,
) -> Behaviour:
    """The picking robot's tree: ``Selector(memory=False)[battery_guard, pick_branch, Idle]``."""
    ns = normalize_namespace(namespace)
    return _robot_tree("PickingRobot", ns, backend, clock, battery, pick_branch(ns, backend, retries=retries))


def _robot_tree(
    label: str, ns: str, backend: NavigationBackend, clock: Clock, battery: BatteryModel, work: Behaviour
) -> Behaviour:
    """``Selector(memory=False)[battery_guard, work, Idle]`` on the robot's own blackboard."""
    robot_blackboard(ns, name=f"{ns}-tree")
    return py_trees.composites.Selector(
        f"{label} {ns}",
        memory=False,
        children=[battery_guard(ns, backend, clock, battery), work, Idle(ns)],
    )


def build_tree(
    kind: TreeKind | str,
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    *,
    retries: int = 6,
    traffic: bool = False,
) -> Behaviour:
    """Build the tree of ``kind`` (a :class:`fleet.types.TreeKind`, or its name as a user
    wrote it: ``"patrol"``, ``"picking"``); ``traffic=True`` builds the traffic-managed variant
    (patrol only). Raises :class:`~fleet.errors.FleetError` for an unknown kind, or for a
    picking tree with traffic. The tree of every kind, ``"tasks"`` included:
    :func:`nodes.task_tree.build_robot_tree`."""
    try:
        tree = TreeKind(kind)
    except ValueError:
        raise FleetError(
            f"unknown behavior tree kind {kind!r}; known kinds: {', '.join(k.value for k in TreeKind)}"
        ) from None
    if tree is TreeKind.TASKS:
        raise FleetError("the tasks tree is built by nodes.task_tree.build_robot_tree")
    if tree is TreeKind.PATROL:
        return patrol_tree(namespace, backend, clock, battery, retries=retries, traffic=traffic)
    if traffic:
        raise FleetError(
            "traffic management drives patrol trees only; run picking trees without traffic management"
        )
    return picking_tree(namespace, backend, clock, battery, retries=retries)


def dump_tree(root: Behaviour, *, unicode: bool = False, show_status: bool = False) -> str:
    """A text drawing of the tree under ``root`` (``py_trees.display.ascii_tree`` or
    ``unicode_tree``); ``show_status`` adds each node's last status."""
    if unicode:
        return py_trees.display.unicode_tree(root, show_status=show_status)
    return py_trees.display.ascii_tree(root, show_status=show_status)
