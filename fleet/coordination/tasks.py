"""Tasks and the task book: every piece of work the coordinator hands out, behind one protocol.

A :class:`Task` is one unit of work held by at most one robot at a time. Its kind decides
where a robot can start it (:meth:`Task.entries`), what the robot is sent
(:meth:`Task.order`), how a status carrying the assignment's id moves it on
(:meth:`Task.record`) and whether it is finished. The kinds:

* :class:`PatrolRoute` (``TaskKind.PATROL``): a route kept covered, counted in laps; finished
  after ``laps`` laps over all its assignments, or never (``laps`` ``None``: until canceled).
* :class:`Pick` (``TaskKind.PICK``): a pick (shelf, dwell, drop) done once; finished when the
  robot reports its steps done (or its ``picks_done`` rises).
* :class:`~fleet.coordination.kinds.StepTask` (``go_to``, ``inspection``, ``park``,
  ``charge``): steps the robot runs once; finished when it reports them done.

Every kind states the way traffic management must reserve for it with
:meth:`Task.traffic_route` (a :class:`TrafficRoute`: roadmap nodes, looped or not). Besides
the protocol, a task may have ``priority`` (int, higher is matched first; default 0),
``only`` (the one robot allowed to take it; default any) and ``laps`` (a patrol's target);
read them with :func:`priority_of`, :func:`only_of`, :func:`laps_target`.

A status that carries an assignment's id and reports ``result_id`` equal to it finishes the
task whatever its kind: ``result`` ``succeeded`` completes it, ``failed: ...`` fails it
(:class:`~fleet.coordination.lifecycle.TaskState`). The book tells its ``listener``
(:class:`~fleet.coordination.lifecycle.TaskListener`) about every transition.

The :class:`TaskBook` holds every task, who holds it, the assignment records (one
:class:`~fleet.coordination.views.Assignment` per hand-over, fresh id each time), the
reassignments and the tasks waiting to be handed over again. A task is *waiting* (no robot,
not finished), *held* (a robot has an assignment for it) or *done* (finished; never handed
out again). A new kind plugs in by implementing :class:`Task`; the book, the matcher, the
health checks and the order (re)sending work on the protocol only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt

from fleet.coordination import archive
from fleet.coordination.archive import Archive
from fleet.coordination.lifecycle import TaskListener, TaskState
from fleet.coordination.views import Assignment, Observation, Reassignment, TaskOrder
from fleet.messages import Step
from fleet.types import Pose2D, TaskKind

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig, PickTask
    from fleet.roadmap.distances import Distances
    from fleet.roadmap.graph import Roadmap

#: Prefix of the ids of idle orders (tasks bring their own, :attr:`Task.id_prefix`).
IDLE_PREFIX = "i"

#: The result a robot reports for a task it finished (``StatusRecord.result``).
SUCCEEDED = "succeeded"


@dataclass(frozen=True)
class TrafficRoute:
    """What traffic management reserves for a task: its roadmap ``nodes`` in driving order,
    driven as a loop (``loop``, a patrol) or once, stopping at each node (a pick, a go_to, an
    inspection)."""

    nodes: tuple[str, ...]
    loop: bool = False


def priority_of(task: object) -> int:
    """A task's ``priority`` (higher is matched first; 0 if it has none)."""
    return int(getattr(task, "priority", 0))


def only_of(task: object) -> str | None:
    """The one robot a task may go to (its ``only``), or ``None``: any robot."""
    only = getattr(task, "only", None)
    return None if only is None else str(only)


def laps_target(task: object) -> int | None:
    """A patrol's target laps (its ``laps``), or ``None``: until canceled."""
    laps = getattr(task, "laps", None)
    return None if laps is None else int(laps)


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

    def traffic_route(self) -> TrafficRoute | PatrolRoute | None:
        """The route traffic management reserves for the robot (nodes, looped or not), or
        ``None`` (not managed)."""
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

    As a :class:`Task`: any of its nodes is an entry (the lap starts there), and its
    assignment counts the highest ``laps`` its robot reported for the id (also after the
    route was taken back: a lap driven is a lap driven). It is finished when its assignments
    drove ``laps`` laps in total (the book counts), never if ``laps`` is ``None``.
    ``priority`` / ``only``: see the module docstring."""

    name: str
    poses: tuple[Pose2D, ...]
    nodes: tuple[str, ...]
    robot: str | None = None
    laps: int | None = None
    priority: int = 0
    only: str | None = None

    @property
    def loop(self) -> bool:
        """Traffic management drives a patrol as a loop."""
        return True

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

    def traffic_route(self) -> TrafficRoute | PatrolRoute | None:
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
    stall). A robot running the task tree gets the pick as steps (drive to the shelf, wait
    ``dwell_s``, drive to the drop; ``nodes`` are the roadmap nodes nearest shelf and drop,
    its traffic route) and reports them done (the generic result, see the module docstring).
    """

    spec: PickTask
    nodes: tuple[str, str] | None = None
    priority: int = 0
    only: str | None = None

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

    def traffic_route(self) -> TrafficRoute | PatrolRoute | None:
        return None if self.nodes is None else TrafficRoute(self.nodes)

    def steps(self) -> tuple[Step, ...]:
        """Shelf, dwell, drop as steps (nodes for traffic management when known)."""
        sp = self.spec
        shelf_node, drop_node = self.nodes if self.nodes is not None else (None, None)
        return (
            Step("drive", sp.shelf, shelf_node, name=sp.shelf_station or "shelf"),
            Step("wait", duration_s=float(sp.dwell_s), name="dwell"),
            Step("drive", sp.drop, drop_node, name=sp.drop_station or "drop"),
        )

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
        return TaskOrder(
            robot, a.task_id, TaskKind.PICK, None, (), charger, pick=self.spec, steps=self.steps()
        )


class TaskBook:
    """Every task, who holds it, and every assignment and reassignment (see the module
    docstring). ``distances`` indexes the roadmap nodes of the tasks' entries.

    Attributes (read them, change them through the methods): ``tasks`` by name in the order
    added; ``holder`` task name -> robot (``None``: nobody); ``done`` finished task names
    (completed, failed or canceled: never handed out again); ``records`` the assignments in
    the order made; ``by_id`` the same by task id; ``reassignments`` the tasks taken back;
    ``archive`` the totals of the old assignments and reassignments no longer kept one by one
    (bounded logs: :mod:`fleet.coordination.archive`);
    ``pending`` task name -> its reassignment while the task waits for a new robot;
    ``laps`` task name -> laps driven over all its assignments; ``listener`` told about every
    lifecycle transition (:class:`~fleet.coordination.lifecycle.TaskListener`).

    Ids: :meth:`next_id` counts from ``first_id`` (a restarted coordinator passes the first
    id its durable book has not handed out), and calls ``on_id(counter)`` after every id so
    that the caller can persist how far it got.
    """

    def __init__(self, distances: Distances, first_id: int = 1) -> None:
        self.distances = distances
        self.tasks: dict[str, Task] = {}
        self.holder: dict[str, str | None] = {}
        self.done: set[str] = set()
        self.records: list[Assignment] = []
        self.by_id: dict[str, Assignment] = {}
        self.reassignments: list[Reassignment] = []
        self.archive = Archive()
        self.pending: dict[str, Reassignment] = {}
        self.laps: dict[str, int] = {}
        self.listener: TaskListener | None = None
        self.on_id: Callable[[int], None] | None = None
        self._counter = first_id - 1
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
        self.laps.setdefault(task.name, 0)
        self._entries[task.name] = (idx, off)
        self._row[task.name] = len(self._row)
        self._offsets = self._offsets or any(o != 0.0 for o in off)
        self._matrix = None

    def forget(self, name: str) -> None:
        """Drop the finished task ``name`` from :attr:`tasks` (its records stay), so that a
        long run's book holds only the tasks still to do. No-op for an unknown name."""
        if name not in self.tasks or name not in self.done:
            return
        del self.tasks[name], self.holder[name], self._entries[name]
        self.laps.pop(name, None)
        self._row = {n: i for i, n in enumerate(self._entries)}
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
        if self.on_id is not None:
            self.on_id(self._counter)
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
        if len(self.records) > 2 * archive.KEEP_RECORDS:  # amortized: a pass every KEEP_RECORDS
            self._archive_old(now)
        self.holder[name] = robot
        r = self.pending.pop(name, None)
        if r is not None:
            r.to_robot, r.new_task_id, r.t_reassigned = robot, task_id, now
        if self.listener is not None:
            self.listener.assigned(name, a, now)
        return a, r

    def restore(self, name: str, robot: str, task_id: str, now: float, started: bool) -> Assignment:
        """A restarted coordinator's lease from its durable book: ``robot`` held task
        ``name`` under ``task_id``. The assignment is marked ``restored`` until the robot
        confirms it (the listener is not told: nothing changed)."""
        task = self.tasks[name]
        a = Assignment(task_id=task_id, name=name, kind=task.kind, robot=robot, t_assigned=now, restored=True)
        a.t_started = now if started else None
        self.records.append(a)
        self.by_id[task_id] = a
        self.holder[name] = robot
        return a

    def release(self, a: Assignment, now: float, reason: str) -> Reassignment:
        """Take ``a``'s task back from its robot for ``reason``: it waits for another robot."""
        a.ended = now
        a.end_reason = reason
        self.holder[a.name] = None
        r = Reassignment(t=now, route=a.name, from_robot=a.robot, reason=reason, old_task_id=a.task_id)
        self.reassignments.append(r)
        if len(self.reassignments) > 2 * archive.KEEP_RECORDS:
            drop = len(self.reassignments) - archive.KEEP_RECORDS
            del self.reassignments[:drop]
            self.archive.reassignments += drop
        self.pending[a.name] = r
        if self.listener is not None:
            self.listener.released(a.name, a, now, reason)
        return r

    def _archive_old(self, now: float) -> None:
        """Fold the old ended assignments into :attr:`archive` (:func:`archive.split_old`)."""
        self.records, old = archive.split_old(self.records, now)
        for a in old:
            self.archive.add(a)
            if self.by_id.get(a.task_id) is a:
                del self.by_id[a.task_id]

    def finish(
        self, name: str, a: Assignment | None, now: float, state: TaskState, message: str = ""
    ) -> None:
        """Task ``name`` ends in the terminal ``state`` (``a``: its last assignment, which
        ends too): never handed out again."""
        if name in self.done:
            return
        self.holder[name] = None
        self.pending.pop(name, None)
        self.done.add(name)
        if a is not None and a.ended is None:
            a.ended = now
            a.end_reason = state.value
        if self.listener is not None:
            self.listener.finished(name, a, now, state, message)

    def record(
        self, robot: str, obs: Observation, now: float, active: Assignment | None
    ) -> Assignment | None:
        """A status of ``robot`` carrying ``obs.task_id``; ``active`` is the robot's current
        assignment. Returns the assignment if this status finished its task (then done:
        completed, or failed if the robot reported it failed)."""
        if obs.task_id is None:
            return None
        a = self.by_id.get(obs.task_id)
        if a is None or a.robot != robot or a.name not in self.tasks:
            return None
        task = self.tasks[a.name]
        is_active = active is a
        if is_active and a.t_started is None and a.ended is None:
            a.t_started = now
            if self.listener is not None:
                self.listener.started(a.name, a, now)
        laps_before = a.laps
        finished = task.record(a, obs, now, is_active)
        note = self._progress(a, obs, laps_before, is_active)
        if note is not None and self.listener is not None:
            self.listener.progressed(a.name, a, now, self.laps.get(a.name, 0), note)
        target = laps_target(task)
        if target is not None and self.laps.get(a.name, 0) >= target:
            finished = True
        state, message = TaskState.COMPLETED, ""
        if obs.result_id == a.task_id and obs.result:
            finished = True
            if obs.result != SUCCEEDED:
                state, message = TaskState.FAILED, obs.result
        if not finished or not is_active:  # only the robot's current assignment finishes a task
            return None
        if a.t_completed is None and state is TaskState.COMPLETED:
            a.t_completed = now
        self.finish(a.name, a, now, state, message)
        return a

    def _progress(self, a: Assignment, obs: Observation, laps_before: int, active: bool) -> str | None:
        """Count laps and steps; what changed (``""``: nothing worth a note), ``None`` if nothing."""
        notes: list[str] = []
        if a.laps > laps_before:
            self.laps[a.name] = self.laps.get(a.name, 0) + a.laps - laps_before
            notes.append(f"lap {self.laps[a.name]} by {a.robot}")
        if active and obs.steps_done > a.steps_done:
            steps = getattr(self.tasks[a.name], "steps", None)
            seq: tuple[Step, ...] = steps() if callable(steps) else tuple(steps or ())
            for k in range(a.steps_done, min(obs.steps_done, len(seq))):
                st = seq[k]
                if st.action == "capture":
                    where = "" if obs.pose is None else f" at ({obs.pose.x:.2f}, {obs.pose.y:.2f})"
                    notes.append(f"capture {st.name!r}{where} by {a.robot}")
            a.steps_done = obs.steps_done
            notes.append(f"step {a.steps_done}/{len(seq)}" if seq else f"step {a.steps_done}")
        return "; ".join(notes) if notes else None


def patrol_routes(config: FleetConfig) -> list[PatrolRoute]:
    """The config's routes as :class:`PatrolRoute` values (one lap each, roadmap node per pose)."""
    out = []
    nodes_of: dict[int, tuple[str, ...]] = {}  # by the lap's identity: route copies share it
    for r in config.routes:
        poses = config.route_poses(r)
        nodes = nodes_of.get(id(poses))
        if nodes is None:
            nodes = nodes_of[id(poses)] = tuple(config.roadmap.nearest_node(p.x, p.y) for p in poses)
        out.append(PatrolRoute(r.name, poses, nodes, r.robot))
    return out
