"""Tasks and the task book: every piece of work the coordinator hands out, behind one protocol.

A :class:`Task` is one unit of work held by at most one robot at a time. Its kind decides
where a robot can start it (:meth:`Task.entries`), what the robot is sent
(:meth:`Task.order`), how a status carrying the assignment's id moves it on
(:meth:`Task.record`) and whether it is finished. Two kinds exist:

* :class:`PatrolRoute` (``TaskKind.PATROL``): a route kept covered, counted in laps; never
  finished, so it stays with its robot until taken back. Traffic management sees it
  (:meth:`Task.traffic_route`).
* :class:`Pick` (``TaskKind.PICK``): a config pick done once; finished when the robot's
  ``picks_done`` rises.

The :class:`TaskBook` holds every task, who holds it, the assignment records (one
:class:`~fleet.coordination.views.Assignment` per hand-over, fresh id each time), the
reassignments and the tasks waiting to be handed over again. A task is *waiting* (no robot,
not finished), *held* (a robot has an assignment for it) or *done* (finished; never handed
out again). A new kind plugs in by implementing :class:`Task`; the book, the matcher, the
health checks and the order (re)sending work on the protocol only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt

from fleet.coordination.views import Assignment, Observation, Reassignment, TaskOrder
from fleet.types import Pose2D, TaskKind

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig, PickTask
    from fleet.roadmap.distances import Distances
    from fleet.roadmap.graph import Roadmap

#: Prefix of the ids of idle orders (tasks bring their own, :attr:`Task.id_prefix`).
IDLE_PREFIX = "i"

IndexMatrix = npt.NDArray[np.int64]
FloatMatrix = npt.NDArray[np.float64]


class Task(Protocol):
    """What the coordinator needs from a kind of task.

    ``name`` is unique in a book; ``robot`` a preferred robot (matched first when it is
    free), or ``None``; ``id_prefix`` starts the ids of its assignments (``p`` for
    ``p-0001``); ``stall_grace_s`` is how much longer than ``stuck_reassign_s`` its robot may
    stand still in a driving mode before it counts as stuck (e.g. a pick's dwell at the shelf).
    """

    @property
    def name(self) -> str: ...

    @property
    def kind(self) -> TaskKind: ...

    @property
    def robot(self) -> str | None: ...

    @property
    def id_prefix(self) -> str: ...

    @property
    def stall_grace_s(self) -> float: ...

    def entries(self, roadmap: Roadmap) -> Sequence[tuple[str, float]]:
        """Where a robot can start the task: ``(roadmap node, extra distance from the node in
        m)`` pairs; the matcher picks the nearest and passes its index to :meth:`poses_from`."""
        ...

    def poses_from(self, entry: int) -> tuple[Pose2D, ...]:
        """The poses the robot drives (``map`` frame) when it starts at entry ``entry``."""
        ...

    def traffic_route(self) -> PatrolRoute | None:
        """The route traffic management reserves for the robot, or ``None`` (not managed)."""
        ...

    def record(self, a: Assignment, obs: Observation, now: float, active: bool) -> bool:
        """Apply a status of ``a.robot`` that carries ``a.task_id`` (``active``: ``a`` is still
        the robot's assignment). Returns True when the task is finished (done for good)."""
        ...

    def order(self, robot: str, a: Assignment, charger: Pose2D | None) -> TaskOrder:
        """The order that sends ``robot`` on assignment ``a``."""
        ...


@dataclass(frozen=True)
class PatrolRoute:
    """A patrol route as the coordinator holds it: one lap of ``poses`` (map frame), the
    roadmap node at each pose (``nodes[i]`` for ``poses[i]``), and an optional preferred robot.

    As a :class:`Task`: any of its nodes is an entry (the lap starts there), it is never
    finished, and its assignment counts the highest ``laps`` its robot reported for the id
    (also after the route was taken back: a lap driven is a lap driven)."""

    name: str
    poses: tuple[Pose2D, ...]
    nodes: tuple[str, ...]
    robot: str | None = None

    @property
    def kind(self) -> TaskKind:
        return TaskKind.PATROL

    @property
    def id_prefix(self) -> str:
        return "p"

    @property
    def stall_grace_s(self) -> float:
        return 0.0

    def entries(self, roadmap: Roadmap) -> Sequence[tuple[str, float]]:
        return [(n, 0.0) for n in self.nodes]

    def poses_from(self, entry: int) -> tuple[Pose2D, ...]:
        return self.poses[entry:] + self.poses[:entry]

    def traffic_route(self) -> PatrolRoute | None:
        return self

    def record(self, a: Assignment, obs: Observation, now: float, active: bool) -> bool:
        if obs.laps > a.laps:
            if a.t_completed is None:
                a.t_completed = now
            a.laps = obs.laps
        return False

    def order(self, robot: str, a: Assignment, charger: Pose2D | None) -> TaskOrder:
        return TaskOrder(robot, a.task_id, TaskKind.PATROL, a.name, a.poses, charger)


@dataclass(frozen=True)
class Pick:
    """A config pick (``spec``) as a :class:`Task`: entered at the roadmap node nearest its
    shelf, done once.

    Completion: the first status of the active assignment's robot carrying its id sets the
    baseline ``picks_done``; a later one with a higher ``picks_done`` finishes the pick. Only
    the active assignment can complete, so a late status of a robot the pick was taken from
    cannot. The robot's stall grace is the pick's ``dwell_s`` (standing at the shelf is no
    stall)."""

    spec: PickTask

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def kind(self) -> TaskKind:
        return TaskKind.PICK

    @property
    def robot(self) -> str | None:
        return self.spec.robot

    @property
    def id_prefix(self) -> str:
        return "k"

    @property
    def stall_grace_s(self) -> float:
        return self.spec.dwell_s

    def entries(self, roadmap: Roadmap) -> Sequence[tuple[str, float]]:
        shelf = self.spec.shelf
        node = roadmap.nearest_node(shelf.x, shelf.y)
        px, py = roadmap.pos(node)
        return [(node, math.hypot(shelf.x - px, shelf.y - py))]

    def poses_from(self, entry: int) -> tuple[Pose2D, ...]:
        return ()

    def traffic_route(self) -> PatrolRoute | None:
        return None

    def record(self, a: Assignment, obs: Observation, now: float, active: bool) -> bool:
        if not active:
            return False
        if a.base is None:
            a.base = obs.picks_done
        elif obs.picks_done > a.base:
            a.t_completed = now
            return True
        return False

    def order(self, robot: str, a: Assignment, charger: Pose2D | None) -> TaskOrder:
        return TaskOrder(robot, a.task_id, TaskKind.PICK, None, (), charger, pick=self.spec)


class TaskBook:
    """Every task, who holds it, and every assignment and reassignment (see the module
    docstring). ``distances`` indexes the roadmap nodes of the tasks' entries.

    Attributes (read them, change them through the methods): ``tasks`` by name in the order
    added; ``holder`` task name -> robot (``None``: nobody); ``done`` finished task names;
    ``records`` every assignment in the order made; ``by_id`` the same by task id;
    ``reassignments`` every task taken back; ``pending`` task name -> its reassignment while
    the task waits for a new robot.
    """

    def __init__(self, distances: Distances) -> None:
        self.distances = distances
        self.tasks: dict[str, Task] = {}
        self.holder: dict[str, str | None] = {}
        self.done: set[str] = set()
        self.records: list[Assignment] = []
        self.by_id: dict[str, Assignment] = {}
        self.reassignments: list[Reassignment] = []
        self.pending: dict[str, Reassignment] = {}
        self._counter = 0
        self._entries: dict[str, tuple[list[int], list[float]]] = {}
        self._row: dict[str, int] = {}
        self._matrix: tuple[IndexMatrix, FloatMatrix] | None = None
        self._offsets = False

    # -- tasks ---------------------------------------------------------------------------

    def add(self, task: Task) -> None:
        """Add ``task`` (waiting). Raises ``ValueError`` if its name is taken or it has an
        entry node that is not on the roadmap."""
        if task.name in self.tasks:
            raise ValueError(f"TaskBook: duplicate task name {task.name!r}")
        idx, off = [], []
        for node, extra in task.entries(self.distances.roadmap):
            if node not in self.distances.index:
                raise ValueError(f"TaskBook: task {task.name!r} enters at {node!r}, not a roadmap node")
            idx.append(self.distances.index[node])
            off.append(float(extra))
        if not idx:  # no entry: priced as if it started at the first node
            idx, off = [0], [0.0]
        self.tasks[task.name] = task
        self.holder[task.name] = None
        self._entries[task.name] = (idx, off)
        self._row[task.name] = len(self._row)
        self._offsets = self._offsets or any(o != 0.0 for o in off)
        self._matrix = None

    def waiting(self, kind: TaskKind | None = None) -> list[str]:
        """Names of the tasks neither held nor done (of ``kind``, if given), in the order added."""
        return [
            n
            for n, h in self.holder.items()
            if h is None and n not in self.done and (kind is None or self.tasks[n].kind is kind)
        ]

    def entry_matrix(self, names: Sequence[str]) -> tuple[IndexMatrix, FloatMatrix, bool]:
        """For tasks ``names``: their entry nodes' indexes in :attr:`distances` and the extra
        distances (m), one row per task, padded with the last entry; and whether any extra
        distance is not zero."""
        if self._matrix is None:
            width = max((len(i) for i, _ in self._entries.values()), default=1)
            m = np.zeros((len(self._entries), width), dtype=np.int64)
            o = np.zeros((len(self._entries), width), dtype=float)
            for r, (idx, off) in enumerate(self._entries.values()):
                m[r, :], o[r, :] = idx[-1], off[-1]
                m[r, : len(idx)], o[r, : len(off)] = idx, off
            self._matrix = (m, o)
        rows = np.array([self._row[n] for n in names], dtype=np.int64)
        m, o = self._matrix
        return m[rows], o[rows], self._offsets

    # -- ids, hand-over, take-back, completion -----------------------------------------

    def next_id(self, prefix: str) -> str:
        """A fresh id ``<prefix>-0001``: one counter for every prefix, never reused."""
        self._counter += 1
        return f"{prefix}-{self._counter:04d}"

    def assign(
        self, name: str, robot: str, task_id: str, poses: tuple[Pose2D, ...], now: float
    ) -> tuple[Assignment, Reassignment | None]:
        """Record that task ``name`` goes to ``robot`` under ``task_id``. Returns the new
        assignment and the pending reassignment it completes, if the task was taken back."""
        task = self.tasks[name]
        a = Assignment(task_id=task_id, name=name, kind=task.kind, robot=robot, t_assigned=now, poses=poses)
        self.records.append(a)
        self.by_id[task_id] = a
        self.holder[name] = robot
        r = self.pending.pop(name, None)
        if r is not None:
            r.to_robot, r.new_task_id, r.t_reassigned = robot, task_id, now
        return a, r

    def release(self, a: Assignment, now: float, reason: str) -> Reassignment:
        """Take ``a``'s task back from its robot for ``reason``: it waits for another robot."""
        a.ended = now
        a.end_reason = reason
        self.holder[a.name] = None
        r = Reassignment(t=now, route=a.name, from_robot=a.robot, reason=reason, old_task_id=a.task_id)
        self.reassignments.append(r)
        self.pending[a.name] = r
        return r

    def record(
        self, robot: str, obs: Observation, now: float, active: Assignment | None
    ) -> Assignment | None:
        """A status of ``robot`` carrying ``obs.task_id``; ``active`` is the robot's current
        assignment. Returns the assignment if this status finished its task (then done)."""
        if obs.task_id is None:
            return None
        a = self.by_id.get(obs.task_id)
        if a is None or a.robot != robot:
            return None
        finished = self.tasks[a.name].record(a, obs, now, active is a)
        if not finished or active is not a:  # only the robot's current assignment finishes a task
            return None
        self.holder[a.name] = None
        self.done.add(a.name)
        return a


def patrol_routes(config: FleetConfig) -> list[PatrolRoute]:
    """The config's routes as :class:`PatrolRoute` values (one lap each, roadmap node per pose)."""
    out = []
    for r in config.routes:
        poses = config.route_poses(r)
        nodes = tuple(config.roadmap.nearest_node(p.x, p.y) for p in poses)
        out.append(PatrolRoute(r.name, poses, nodes, r.robot))
    return out
