"""The navigation backend protocol: the one contract between behavior-tree leaves and a robot.

A backend drives one robot, identified by its ROS-style namespace (``/robot1``). The
in-process simulator (:mod:`sim.backend`), the Zenoh bridge to a simulator in another
process, the ROS 2 / Nav2 adapter and the SUMO adapter each implement it; the conformance
suite in ``tests/conformance`` checks that they behave alike.

Contract:

* :meth:`NavigationBackend.send_goal` never blocks. It returns a fresh goal id at once; the
  goal starts ``PENDING`` and becomes ``EXECUTING`` when the server accepts it (or
  ``REJECTED``).
* A robot executes one *motion* goal at a time (:data:`fleet.types.MOTION_GOAL_KINDS`:
  navigation, FollowPath, the behaviors). A new motion goal preempts the one executing: the
  old goal ends ``ABORTED`` (Nav2's action servers abort the goal they drop) and the new one
  runs. Goals that only compute (:data:`fleet.types.COMPUTE_GOAL_KINDS`: ComputePathToPose,
  ComputePathThroughPoses, SmoothPath, ClearCostmaps) run beside it, as Nav2's planner,
  smoother and costmap servers run beside its controller: they neither preempt the motion
  goal nor are preempted by it. Their result (``GoalState.path`` for the planners and the
  smoother) is in the terminal state; a backend may finish them before ``send_goal``
  returns.
* A backend that cannot execute a goal kind at all (SUMO vehicles cannot follow a free path
  and have no costmaps) ends such a goal ``REJECTED`` with a message saying why.
* :meth:`NavigationBackend.goal_state` is a pure read: polling it any number of times changes
  nothing. Ids are never reused, so a stale id can never observe (or complete) a newer goal.
* :meth:`NavigationBackend.cancel_goal` is idempotent: canceling a finished or unknown goal is
  a no-op. A canceled goal ends ``CANCELED`` and the robot stops.
* If the server goes away mid-goal, the goal ends ``ABORTED`` with
  ``ErrorCode.SERVER_UNAVAILABLE`` instead of staying ``EXECUTING`` forever.

The batch query: a fleet loop reads every robot's state and goal every tick. :func:`query_batch`
answers for many backends at once as a :class:`NavBatch` of NumPy arrays: one call to the
world's :class:`BatchNavigation` when the backends share one (their ``batch_server``), else a
loop over ``robot_state`` / ``goal_state`` (:func:`loop_batch`). Its rows agree with the
per-goal queries (``check_backend``'s ``batch_query_agrees_with_per_goal_queries`` case).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from fleet.types import Goal, GoalState, GoalStatus, RobotState


class Clock(Protocol):
    """A source of time in seconds. The simulator's clock is simulated time."""

    def now(self) -> float: ...


@runtime_checkable
class NavigationBackend(Protocol):
    """Drives one namespaced robot. See the module docstring for the contract."""

    @property
    def namespace(self) -> str:
        """The robot's namespace, e.g. ``/robot1``."""
        ...

    def send_goal(self, goal: Goal) -> str:
        """Send ``goal``; return its id at once (never blocks)."""
        ...

    def goal_state(self, goal_id: str) -> GoalState:
        """Return the latest state of ``goal_id``. Raises ``KeyError`` for an id never issued."""
        ...

    def cancel_goal(self, goal_id: str) -> None:
        """Ask to cancel ``goal_id``; a no-op if it already finished."""
        ...

    def robot_state(self) -> RobotState:
        """Return the robot's current pose, battery and health."""
        ...


# -- the batch query ---------------------------------------------------------------------------

#: ``NavBatch.goal_status`` code of each :class:`GoalStatus` (its index in the enum).
GOAL_CODES: dict[GoalStatus, int] = {s: i for i, s in enumerate(GoalStatus)}
#: The :class:`GoalStatus` of each code of ``NavBatch.goal_status``.
GOAL_STATUSES: tuple[GoalStatus, ...] = tuple(GoalStatus)
#: ``NavBatch.goal_status`` of a row without a goal id, or with an id the backend does not know.
NO_GOAL = -1


@dataclass(frozen=True, eq=False)
class NavBatch:
    """Robot states and goal states of many robots, one row each, as NumPy arrays.

    Row ``i`` is robot ``namespaces[i]`` (a robot may appear in several rows) and goal
    ``goal_ids[i]`` (``None``: no goal asked for in that row). Robot columns, as
    :class:`~fleet.types.RobotState`: ``x``, ``y`` (m, ``map``), ``theta`` (rad) are the pose,
    NaN when the pose is unknown; ``battery`` (fraction), ``distance_m`` (odometer, m),
    ``collisions``, and the flags ``charging``, ``stuck``, ``localized``,
    ``navigation_ready``. Goal columns, as :class:`~fleet.types.GoalState`: ``goal_status`` (the
    index of the status in :class:`GoalStatus`, :data:`GOAL_CODES`; :data:`NO_GOAL` for no id or
    an unknown id), ``goal_error`` (``error_code``) and ``distance_remaining`` (the feedback's
    ``distance_remaining_m``, NaN when absent).
    """

    namespaces: tuple[str, ...]
    goal_ids: tuple[str | None, ...]
    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    theta: npt.NDArray[np.float64]
    battery: npt.NDArray[np.float64]
    distance_m: npt.NDArray[np.float64]
    collisions: npt.NDArray[np.int64]
    charging: npt.NDArray[np.bool_]
    stuck: npt.NDArray[np.bool_]
    localized: npt.NDArray[np.bool_]
    navigation_ready: npt.NDArray[np.bool_]
    goal_status: npt.NDArray[np.int8]
    goal_error: npt.NDArray[np.int32]
    distance_remaining: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.namespaces)

    def status(self, i: int) -> GoalStatus | None:
        """The goal status of row ``i`` (``None``: no goal, or an id the backend does not know)."""
        code = int(self.goal_status[i])
        return None if code == NO_GOAL else GOAL_STATUSES[code]


@runtime_checkable
class BatchNavigation(Protocol):
    """A world that answers for many of its robots in one call (the simulator, SUMO, the ROS
    adapter's set of robots). A :class:`NavigationBackend` that belongs to one offers it as
    its ``batch_server`` attribute."""

    def query_batch(self, namespaces: Sequence[str], goal_ids: Sequence[str | None]) -> NavBatch:
        """The state of robot ``namespaces[i]`` and of goal ``goal_ids[i]`` in row ``i`` (a pure
        read, like ``robot_state`` and ``goal_state``). Raises
        :class:`~fleet.errors.BackendError` for a namespace the world does not have and
        ``ValueError`` when the two sequences differ in length; an unknown goal id is
        :data:`NO_GOAL`, not an error."""
        ...


class RowSource(Protocol):
    """One robot's reads, as a batch row is built from them (a :class:`NavigationBackend`)."""

    def robot_state(self) -> RobotState: ...

    def goal_state(self, goal_id: str) -> GoalState: ...


def loop_batch(backends: Sequence[RowSource], goal_ids: Sequence[str | None]) -> NavBatch:
    """The :class:`NavBatch` of ``backends[i]`` and ``goal_ids[i]`` built by calling each
    backend's ``robot_state`` and ``goal_state`` (the fallback for backends without a batch
    server; its rows agree with per-goal queries by construction)."""
    if len(backends) != len(goal_ids):
        raise ValueError(f"loop_batch: {len(backends)} backends but {len(goal_ids)} goal ids")
    return batch_from_states(
        [getattr(b, "namespace", "") for b in backends],
        goal_ids,
        [b.robot_state() for b in backends],
        [_goal_or_none(b, g) for b, g in zip(backends, goal_ids, strict=True)],
    )


def _goal_or_none(backend: RowSource, goal_id: str | None) -> GoalState | None:
    if goal_id is None:
        return None
    try:
        return backend.goal_state(goal_id)
    except KeyError:
        return None


def batch_from_states(
    namespaces: Sequence[str],
    goal_ids: Sequence[str | None],
    robots: Sequence[RobotState],
    goals: Sequence[GoalState | None],
) -> NavBatch:
    """A :class:`NavBatch` from per-robot snapshots (``goals[i]``: ``None`` for no goal)."""
    nan = math.nan
    poses = [(r.pose.x, r.pose.y, r.pose.theta) if r.pose is not None else (nan, nan, nan) for r in robots]
    xyz = np.array(poses, dtype=np.float64).reshape(len(robots), 3)
    return NavBatch(
        namespaces=tuple(namespaces),
        goal_ids=tuple(goal_ids),
        x=xyz[:, 0].copy(),
        y=xyz[:, 1].copy(),
        theta=xyz[:, 2].copy(),
        battery=np.array([r.battery for r in robots], dtype=np.float64),
        distance_m=np.array([r.distance_m for r in robots], dtype=np.float64),
        collisions=np.array([r.collisions for r in robots], dtype=np.int64),
        charging=np.array([r.charging for r in robots], dtype=np.bool_),
        stuck=np.array([r.stuck for r in robots], dtype=np.bool_),
        localized=np.array([r.localized for r in robots], dtype=np.bool_),
        navigation_ready=np.array([r.navigation_ready for r in robots], dtype=np.bool_),
        goal_status=np.array([NO_GOAL if g is None else GOAL_CODES[g.status] for g in goals], dtype=np.int8),
        goal_error=np.array([0 if g is None else g.error_code for g in goals], dtype=np.int32),
        distance_remaining=np.array(
            [
                nan
                if g is None or g.feedback.distance_remaining_m is None
                else g.feedback.distance_remaining_m
                for g in goals
            ],
            dtype=np.float64,
        ),
    )


def state_reader(backend: NavigationBackend) -> Callable[[], RobotState]:
    """What reads ``backend``'s robot state, skipping wrappers that only pass the call on: a
    backend (or wrapper) may offer ``state_reader``, a callable returning exactly what its
    ``robot_state()`` returns; otherwise ``backend.robot_state`` itself. For readers called
    every period for every robot (the agents)."""
    reader = getattr(backend, "state_reader", None)
    return reader if callable(reader) else backend.robot_state


def query_batch(backends: Sequence[NavigationBackend], goal_ids: Sequence[str | None]) -> NavBatch:
    """Robot ``backends[i]``'s state and goal ``goal_ids[i]``'s state in row ``i`` of one
    :class:`NavBatch`. When every backend names the same ``batch_server`` (a
    :class:`BatchNavigation`), that is one call to it; otherwise it is :func:`loop_batch`."""
    if len(backends) != len(goal_ids):
        raise ValueError(f"query_batch: {len(backends)} backends but {len(goal_ids)} goal ids")
    servers = {id(s): s for s in (getattr(b, "batch_server", None) for b in backends)}
    if len(servers) == 1:
        server = next(iter(servers.values()))
        if isinstance(server, BatchNavigation):
            return server.query_batch([b.namespace for b in backends], goal_ids)
    return loop_batch(backends, goal_ids)
