"""The task service: the one place every face (HTTP, WebSocket, Zenoh, CLI, Python client)
submits, cancels and reads tasks, reads robots, and pauses or stops the fleet.

It owns the task records (:class:`~fleet.service.records.TaskRecord`) and mirrors every
change into the durable store (:class:`~fleet.service.store.TaskStore`) before anyone can
see it. The coordinator's task book stays the only thing that decides: the service is
attached to a :class:`~fleet.coordination.state.CoordinatorState` (:meth:`TaskService.attach`)
as its book's lifecycle listener and as a hook that runs at the start of every coordinator
cycle, on the coordinator's thread, where queued submissions and cancels are applied.

Threads: faces call :meth:`submit`, :meth:`cancel`, :meth:`command` and the readers from any
thread; one lock guards the records. A submission is validated (field-named errors, nothing
stored on error), stored (one transaction) and queued for the next cycle at once, so a burst
of submissions is not paced by the coordinator. A cancel of a task the book holds waits
(up to ``wait_s``) for the cycle that applies it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from fleet.coordination.lifecycle import TERMINAL, TaskState
from fleet.coordination.tasks import Task, laps_target, only_of, priority_of
from fleet.errors import InvalidTask, TaskFinished, UnknownTask
from fleet.messages import FleetControl, StatusRecord
from fleet.service.control import FleetSwitch
from fleet.service.factory import TaskFactory, config_spec
from fleet.service.records import TaskEvent, TaskRecord
from fleet.service.specs import TaskSpec, parse_spec, spec_dict

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from fleet.coordination.state import CoordinatorState
    from fleet.coordination.views import Assignment
    from fleet.navigation import Clock
    from fleet.service.store import TaskStore

logger = logging.getLogger(__name__)

#: At most this many events stay in memory (:meth:`TaskService.recent_events`).
RECENT_EVENTS = 2000
#: At most this many tasks are queued for submission at once (a larger burst gets 503s).
MAX_QUEUED_SUBMISSIONS = 100_000

#: What a face is told about: a task event, or the fleet's control state.
Listener = Callable[[TaskEvent | FleetControl], None]


@dataclass
class _Cancel:
    task_id: str
    by: str
    done: threading.Event


class TaskService:
    """Tasks, robots and fleet control for one coordinator (see the module docstring).

    Args:
        config: the fleet config (stations, routes, map, robots).
        clock: the fleet clock (event times).
        store: the durable store, or ``None`` (an in-memory service: nothing survives).
        wall: Unix time (s).
    """

    def __init__(
        self,
        config: FleetConfig,
        clock: Clock,
        store: TaskStore | None = None,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.config = config
        self.clock = clock
        self.store = store
        self.wall = wall
        self.factory = TaskFactory(config)
        self.records: dict[str, TaskRecord] = {}
        self._by_name: dict[str, str] = {}
        self._lock = threading.RLock()
        self._adds: list[tuple[TaskRecord, Task]] = []
        self._cancels: list[_Cancel] = []
        self._forget: list[str] = []
        self._listeners: list[Listener] = []
        self._recent: deque[TaskEvent] = deque(maxlen=RECENT_EVENTS)
        self._event_seq = store.last_event_seq() if store is not None else 0
        self._next_task = (store.counter("task") if store is not None else 0) + 1
        self._id_reserved = store.counter("assignment") if store is not None else 0
        initial = store.get_meta("control") if store is not None else None
        self.switch = FleetSwitch(
            clock,
            self._save_control,
            FleetControl(**initial) if isinstance(initial, dict) else None,
            wall,
        )
        self.switch.sinks.append(self._publish_control)
        self.state: CoordinatorState | None = None
        #: Latest status records of the robots (set by the runner).
        self.robot_source: Callable[[], Sequence[StatusRecord]] = list
        #: Called when a submission, cancel or command arrives (the runner wakes its loop).
        self.on_input: Callable[[], None] | None = None
        #: HTTP requests refused as malformed (invalid JSON or fields, too large; the API counts).
        self.bad_requests = 0
        #: Extra read-only views for the API (traffic reservations...), by name.
        self.views: dict[str, Callable[[], Any]] = {}

    # -- the coordinator side -----------------------------------------------------------------

    @property
    def first_assignment_id(self) -> int:
        """The first assignment id a (re)started coordinator may hand out."""
        return self._id_reserved + 1

    def attach(self, state: CoordinatorState) -> None:
        """Become ``state``'s lifecycle listener and cycle hook; bring the durable book in
        (config tasks recorded or matched by name, stored tasks re-added, leases restored)."""
        self.state = state
        now = float(self.clock.now())
        with self._lock:
            self._restore_book(state, now)
            state.book.listener = self
            state.book.on_id = self._on_id
            state.hooks.append(self._apply)
            state.halted = self.switch.current.paused

    def _on_id(self, counter: int) -> None:
        if counter > self._id_reserved and self.store is not None:
            from fleet.service.store import ID_BLOCK

            self._id_reserved = counter + ID_BLOCK - 1
            self.store.raise_counter("assignment", self._id_reserved)

    def _apply(self, state: CoordinatorState, now: float) -> None:
        """The cycle hook: queued submissions join the book, queued cancels are applied."""
        with self._lock:
            adds, self._adds = self._adds, []
            cancels, self._cancels = self._cancels, []
            forget, self._forget = self._forget, []
        for name in forget:
            state.book.forget(name)
        for rec, task in adds:
            if rec.state is TaskState.CANCELED:
                continue
            try:
                state.add_task(task, now)
            except ValueError as e:  # e.g. an entry node off the roadmap: fail, not crash
                self._finish(rec, TaskState.FAILED, f"cannot be queued: {e}", None, now)
        for c in cancels:
            held = self.records.get(c.task_id)
            if held is not None and not held.state.terminal:
                held.message = f"canceled by {c.by or '?'}"
                try:
                    order = state.cancel(held.name, now)
                except KeyError:
                    self._finish(held, TaskState.CANCELED, held.message, None, now)
                    order = None
                if order is not None:
                    state.send(order)
            c.done.set()
        state.halted = self.switch.current.paused

    # -- TaskListener (the coordinator's thread) ----------------------------------------------

    def _rec(self, name: str) -> TaskRecord | None:
        tid = self._by_name.get(name)
        return None if tid is None else self.records.get(tid)

    def assigned(self, name: str, a: Assignment, now: float) -> None:
        rec = self._rec(name)
        if rec is None:
            return
        with self._lock:
            rec.state, rec.robot, rec.assignment = TaskState.ASSIGNED, a.robot, a.task_id
            rec.attempts += 1
            rec.assigned_at = self.wall()
            rec.started_at = None
            rec.steps_done = 0
            self._change(rec, "assigned", f"to {a.robot} as {a.task_id}", now)

    def started(self, name: str, a: Assignment, now: float) -> None:
        rec = self._rec(name)
        if rec is None or rec.assignment != a.task_id:
            return
        with self._lock:
            rec.state = TaskState.ACTIVE
            rec.started_at = self.wall()
            self._change(rec, "active", f"{a.robot} runs {a.task_id}", now)

    def progressed(self, name: str, a: Assignment, now: float, laps: int, note: str) -> None:
        rec = self._rec(name)
        if rec is None:
            return
        with self._lock:
            rec.laps = laps
            if rec.assignment == a.task_id:
                rec.steps_done = a.steps_done
            self._change(rec, "progress", note, now)

    def released(self, name: str, a: Assignment, now: float, reason: str) -> None:
        rec = self._rec(name)
        if rec is None:
            return
        with self._lock:
            rec.state = TaskState.QUEUED
            self._change(rec, "requeued", f"taken from {a.robot} ({reason})", now)

    def finished(self, name: str, a: Assignment | None, now: float, state: TaskState, message: str) -> None:
        rec = self._rec(name)
        if rec is None:
            return
        with self._lock:
            self._finish(rec, state, rec.message if state is TaskState.CANCELED else message, a, now)
            if rec.source != "config":
                self._forget.append(name)  # dropped from the book at the next cycle

    def _finish(
        self, rec: TaskRecord, state: TaskState, message: str, a: Assignment | None, now: float
    ) -> None:
        with self._lock:
            rec.state = state
            rec.message = message
            rec.ended_at = self.wall()
            if a is not None:
                rec.robot, rec.assignment = a.robot, a.task_id
            self._change(rec, state.value, message or (f"by {a.robot}" if a is not None else ""), now)

    def _change(self, rec: TaskRecord, event: str, text: str, now: float, store: bool = True) -> TaskEvent:
        """Stamp, store (one transaction) and announce a change of ``rec``."""
        rec.updated_at = self.wall()
        self._event_seq += 1
        ev = TaskEvent(
            self._event_seq,
            rec.id,
            event,
            rec.state.value,
            rec.robot,
            rec.assignment,
            text,
            rec.updated_at,
            now,
        )
        if store and self.store is not None:
            self.store.save(rec, ev)
        self._announce(ev)
        return ev

    def _announce(self, ev: TaskEvent | FleetControl) -> None:
        if isinstance(ev, TaskEvent):
            self._recent.append(ev)
        for fn in list(self._listeners):
            try:
                fn(ev)
            except Exception as e:  # noqa: BLE001 - a face's trouble is not the service's
                logger.debug("task event listener failed: %s", e)

    # -- restart: the durable book read back -------------------------------------------------

    def _restore_book(self, state: CoordinatorState, now: float) -> None:
        """Bring the durable task book into a (re)started coordinator's ``state``, once, when
        the service is attached (called with the lock held):

        1. every stored task is read back;
        2. the config's initial tasks (already in the book) are matched to their stored
           records by name; new ones are recorded (one transaction); one that ended stays
           ended (it is not handed out again);
        3. submitted tasks that had not ended are rebuilt from their stored spec and queued
           again (one that no longer fits the config, e.g. a station removed, fails);
        4. every lease (a task ``assigned`` or ``active`` on a robot under an assignment id)
           is restored: the robot keeps the task if its first status carries that id,
           otherwise the task goes back to the queue (``CoordinatorState.restore``).

        Laps driven so far are kept, so an N-lap patrol resumes its count."""
        stored = self.store.load() if self.store is not None else []
        for rec in stored:
            self.records[rec.id] = rec
            self._by_name[rec.name] = rec.id
        self._config_tasks(state, now)
        self._submitted_tasks(state, stored, now)
        for rec in list(self.records.values()):
            if (
                rec.state in (TaskState.ASSIGNED, TaskState.ACTIVE)
                and rec.robot
                and rec.assignment
                and rec.name in state.book.tasks
                and rec.name not in state.book.done
            ):
                state.restore(rec.name, rec.robot, rec.assignment, now, rec.state is TaskState.ACTIVE)
                self._change(rec, "restored", f"lease of {rec.robot} ({rec.assignment}) read back", now)

    def _config_tasks(self, state: CoordinatorState, now: float) -> None:
        book = state.book
        new: list[TaskRecord] = []
        events: list[TaskEvent] = []
        for name, task in list(book.tasks.items()):
            tid = self._by_name.get(name)
            if tid is None:
                tid = f"t-{self._next_task:04d}"
                self._next_task += 1
                rec = self._new_record(tid, name, task, "config", config_spec(task), "config")
                self.records[tid] = rec
                self._by_name[name] = tid
                new.append(rec)
                events.append(self._event(rec, "queued", "from the fleet config"))
                continue
            rec = self.records[tid]
            if rec.state.terminal:
                book.finish(name, None, now, rec.state, rec.message)  # no listener yet: nothing stored
            else:
                book.laps[name] = rec.laps
        if new and self.store is not None:
            self.store.insert(new, events, counter=self._next_task - 1)
        for ev in events:
            self._announce(ev)

    def _submitted_tasks(self, state: CoordinatorState, stored: list[TaskRecord], now: float) -> None:
        for rec in stored:
            if rec.state.terminal:
                continue
            if rec.source == "config":
                if rec.name not in state.book.tasks:
                    rec.state, rec.message = TaskState.FAILED, "not among this run's initial tasks any more"
                    self._change(rec, "failed", rec.message, now)
                continue
            try:
                task = self.factory.build(parse_spec(rec.spec), rec.name, self._parking_taken())
                state.book.add(task)
            except (InvalidTask, ValueError) as e:
                rec.state, rec.message = TaskState.FAILED, f"no longer valid after a restart: {e}"
                self._change(rec, "failed", rec.message, now)
                continue
            state.book.laps[rec.name] = rec.laps

    # -- faces: tasks ------------------------------------------------------------------------

    def submit(self, data: object, by: str = "") -> TaskRecord:
        """Validate and store a task (a parsed JSON object or a :data:`TaskSpec`); it joins
        the coordinator's book at its next cycle. Returns the record (state ``queued``).
        Raises :class:`~fleet.errors.InvalidTask` naming the field; nothing is stored then."""
        spec: TaskSpec = data if not isinstance(data, dict) and hasattr(data, "kind") else parse_spec(data)  # type: ignore[assignment]
        with self._lock:
            if len(self._adds) >= MAX_QUEUED_SUBMISSIONS:
                raise InvalidTask("", "too many submissions waiting for the coordinator; try again")
            n = self._next_task
            tid = f"t-{n:04d}"
            taken = self._parking_taken()
            task = self.factory.build(spec, tid, taken)
            rec = self._new_record(tid, tid, task, "submitted", spec_dict(spec), by)
            ev = self._event(rec, "queued", f"submitted by {by or '?'}")
            if self.store is not None:
                self.store.insert([rec], [ev], counter=n)
            self._next_task = n + 1
            self.records[tid] = rec
            self._by_name[tid] = tid
            self._adds.append((rec, task))
            self._announce(ev)
        if self.on_input is not None:
            self.on_input()
        return rec

    def _new_record(
        self, tid: str, name: str, task: Task, source: str, spec: dict[str, Any], by: str
    ) -> TaskRecord:
        steps = getattr(task, "steps", ())
        n_steps = len(steps() if callable(steps) else steps)
        wall = self.wall()
        return TaskRecord(
            id=tid,
            name=name,
            kind=str(task.kind),
            source=source,
            spec=spec,
            priority=priority_of(task),
            only=only_of(task),
            steps_total=n_steps,
            submitted_by=by,
            created_at=wall,
            updated_at=wall,
        )

    def _event(self, rec: TaskRecord, event: str, text: str) -> TaskEvent:
        self._event_seq += 1
        return TaskEvent(
            self._event_seq,
            rec.id,
            event,
            rec.state.value,
            rec.robot,
            rec.assignment,
            text,
            rec.updated_at,
            float(self.clock.now()),
        )

    def _parking_taken(self) -> list[Any]:
        from fleet.coordination.kinds import StepTask

        out: list[Any] = []
        if self.state is not None:
            for t in self.state.book.tasks.values():
                if isinstance(t, StepTask) and str(t.kind) == "park" and t.name not in self.state.book.done:
                    out.extend(s.pose for s in t.drives())
        out.extend(s.pose for _, t in self._adds if isinstance(t, StepTask) for s in t.drives())
        return out

    def cancel(self, task_id: str, by: str = "", wait_s: float = 5.0) -> TaskRecord:
        """Cancel a task. A task not yet in the book ends at once; otherwise the next
        coordinator cycle takes it from its robot (waited for up to ``wait_s`` wall seconds;
        the record says ``cancel_requested`` if that did not happen in time). Raises
        :class:`~fleet.errors.UnknownTask` or :class:`~fleet.errors.TaskFinished`."""
        with self._lock:
            rec = self.records.get(task_id)
            if rec is None:
                raise UnknownTask(task_id)
            if rec.state in TERMINAL:
                raise TaskFinished(task_id, rec.state.value)
            pending = [a for a in self._adds if a[0].id == task_id]
            if pending:  # not in the book yet
                self._adds = [a for a in self._adds if a[0].id != task_id]
                self._finish(
                    rec, TaskState.CANCELED, f"canceled by {by or '?'}", None, float(self.clock.now())
                )
                return rec
            rec.cancel_requested = True
            c = _Cancel(task_id, by, threading.Event())
            self._cancels.append(c)
        if self.on_input is not None:
            self.on_input()
        c.done.wait(wait_s)
        return rec

    def get(self, task_id: str) -> TaskRecord:
        """The task ``task_id``; :class:`~fleet.errors.UnknownTask` if there is none."""
        with self._lock:
            rec = self.records.get(task_id)
        if rec is None:
            raise UnknownTask(task_id)
        return rec

    def tasks(
        self,
        state: str | None = None,
        kind: str | None = None,
        robot: str | None = None,
        limit: int | None = None,
    ) -> list[TaskRecord]:
        """Tasks (oldest first), filtered by state, kind and robot; the latest ``limit``."""
        with self._lock:
            out = [
                r
                for r in self.records.values()
                if (state is None or r.state == state)
                and (kind is None or r.kind == kind)
                and (robot is None or r.robot == robot)
            ]
        return out[-limit:] if limit else out

    def events(self, task_id: str | None = None, limit: int = 100) -> list[TaskEvent]:
        """The latest events (of one task), oldest first: from the store if there is one."""
        if self.store is not None:
            return self.store.events(task_id, limit)
        evs = [e for e in self._recent if task_id is None or e.task_id == task_id]
        return evs[-limit:]

    def recent_events(self) -> list[TaskEvent]:
        return list(self._recent)

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener`` with every task event and control change (any thread); returns
        the function that stops it."""
        self._listeners.append(listener)

        def stop() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return stop

    def laps_target(self, rec: TaskRecord) -> int | None:
        if self.state is None or rec.name not in self.state.book.tasks:
            return None
        return laps_target(self.state.book.tasks[rec.name])

    # -- faces: fleet control -----------------------------------------------------------------

    def command(self, action: str, by: str = "", reason: str = "") -> FleetControl:
        """Pause, resume, e-stop or release the fleet (:class:`~fleet.service.control.FleetSwitch`)."""
        ctl = self.switch.command(action, by, reason)
        if self.on_input is not None:
            self.on_input()
        return ctl

    @property
    def control(self) -> FleetControl:
        return self.switch.current

    def _save_control(self, ctl: FleetControl) -> None:
        if self.store is not None:
            d = {k: getattr(ctl, k) for k in ctl.__struct_fields__}
            self.store.set_meta("control", d)

    def _publish_control(self, ctl: FleetControl) -> None:
        self._announce(ctl)

    # -- faces: robots -------------------------------------------------------------------------

    def robots(self) -> list[dict[str, Any]]:
        """Every robot's latest state: see :func:`fleet.service.robots.robot_dicts`."""
        from fleet.service.robots import robot_dicts

        return robot_dicts(self.robot_source(), self.state, self.records_by_assignment())

    def records_by_assignment(self) -> dict[str, str]:
        """Assignment id -> task id of the tasks held now."""
        with self._lock:
            return {
                r.assignment: r.id
                for r in self.records.values()
                if r.assignment and r.state in (TaskState.ASSIGNED, TaskState.ACTIVE)
            }
