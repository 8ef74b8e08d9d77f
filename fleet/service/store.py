"""The durable task book: every task, its state, who holds it (the robot leases), its events,
the id counters and the fleet's control state, in SQLite (stdlib ``sqlite3``).

One file, ``<state dir>/tasks.sqlite3``, in WAL mode with ``synchronous=NORMAL``: every state
change is one transaction (the task row, its lease and its event together), committed before
the change is visible to anyone, so a ``kill -9`` at any moment leaves the store as it was
after the last completed change (WAL with ``NORMAL`` is durable against a process crash; a
power cut may lose the last transactions, ``durable=True`` syncs every commit).

Ids are never reused: task ids come from the ``task`` counter, written in the transaction
that stores the task; assignment ids (``p-0042``) from the ``assignment`` counter, reserved
in blocks of :data:`ID_BLOCK` ahead of use, so a restarted coordinator starts after the last
block. Events are bounded (the oldest beyond :data:`MAX_EVENTS` are pruned).
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fleet.coordination.lifecycle import TaskState
from fleet.errors import ServiceError
from fleet.service.records import TaskEvent, TaskRecord

#: The store's file in the state directory.
STORE_FILE = "tasks.sqlite3"
#: Assignment ids are reserved this many at a time.
ID_BLOCK = 1000
#: At most this many task events are kept (the oldest are pruned).
MAX_EVENTS = 100_000
#: Version of the schema (``meta.schema``).
SCHEMA = 1

_COLUMNS = (
    "id",
    "name",
    "kind",
    "source",
    "spec",
    "priority",
    "only",
    "state",
    "robot",
    "assignment",
    "attempts",
    "laps",
    "steps_done",
    "steps_total",
    "message",
    "submitted_by",
    "created_at",
    "assigned_at",
    "started_at",
    "ended_at",
    "updated_at",
)

_DDL = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS counters (name TEXT PRIMARY KEY, value INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS tasks (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE, name TEXT NOT NULL, kind TEXT NOT NULL, source TEXT NOT NULL,
    spec TEXT NOT NULL, priority INTEGER NOT NULL, only TEXT, state TEXT NOT NULL, robot TEXT,
    assignment TEXT, attempts INTEGER NOT NULL, laps INTEGER NOT NULL, steps_done INTEGER NOT NULL,
    steps_total INTEGER NOT NULL, message TEXT NOT NULL, submitted_by TEXT NOT NULL,
    created_at REAL NOT NULL, assigned_at REAL, started_at REAL, ended_at REAL, updated_at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS tasks_state ON tasks (state);
CREATE TABLE IF NOT EXISTS leases (
    robot TEXT PRIMARY KEY, task_id TEXT NOT NULL, assignment TEXT NOT NULL, since REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS events (
    seq INTEGER PRIMARY KEY, task_id TEXT NOT NULL, event TEXT NOT NULL, state TEXT NOT NULL,
    robot TEXT, assignment TEXT, text TEXT NOT NULL, wall REAL NOT NULL, t REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS events_task ON events (task_id, seq);
"""


class TaskStore:
    """The durable task book in ``directory`` (created if missing). Thread-safe: one
    connection, one lock; every method is one transaction. Raises
    :class:`~fleet.errors.ServiceError` if the file cannot be opened or is not a task store."""

    def __init__(self, directory: str | Path, *, durable: bool = False) -> None:
        self.directory = Path(directory)
        self.path = self.directory / STORE_FILE
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(f"PRAGMA synchronous={'FULL' if durable else 'NORMAL'}")
            self._db.executescript(_DDL)
            row = self._db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
            if row is None:
                self._db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA),))
            elif int(row[0]) != SCHEMA:
                raise ServiceError(f"{self.path}: task store schema {row[0]}, expected {SCHEMA}")
        except (sqlite3.Error, OSError) as e:
            raise ServiceError(f"{self.path}: cannot open the task store ({e})") from None
        self._lock = threading.Lock()
        self._events_since_prune = 0
        #: Transactions committed (for benchmarks and tests).
        self.commits = 0

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            db = self._db
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")
            self.commits += 1

    # -- counters and meta ------------------------------------------------------------------

    def counter(self, name: str) -> int:
        """The counter's value (0 if never set)."""
        with self._lock:
            row = self._db.execute("SELECT value FROM counters WHERE name=?", (name,)).fetchone()
        return 0 if row is None else int(row[0])

    def raise_counter(self, name: str, value: int) -> None:
        """Set the counter to ``value`` if that is higher (one transaction)."""
        with self._tx() as db:
            _raise(db, name, value)

    def get_meta(self, key: str) -> Any:
        """A JSON value stored with :meth:`set_meta`, or ``None``."""
        with self._lock:
            row = self._db.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        return None if row is None else json.loads(row[0])

    def set_meta(self, key: str, value: Any) -> None:
        with self._tx() as db:
            db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value)))

    # -- tasks ------------------------------------------------------------------------------

    def load(self) -> list[TaskRecord]:
        """Every task, in the order stored."""
        with self._lock:
            rows = self._db.execute(f"SELECT {', '.join(_COLUMNS)} FROM tasks ORDER BY seq").fetchall()
        return [_record(r) for r in rows]

    def leases(self) -> dict[str, tuple[str, str]]:
        """Robot -> ``(task id, assignment id)`` it holds."""
        with self._lock:
            rows = self._db.execute("SELECT robot, task_id, assignment FROM leases").fetchall()
        return {r[0]: (r[1], r[2]) for r in rows}

    def insert(
        self, recs: Sequence[TaskRecord], events: Sequence[TaskEvent], counter: int | None = None
    ) -> None:
        """Store new tasks and their events in one transaction (and raise the ``task``
        counter to ``counter``). Raises ``sqlite3.IntegrityError`` for an id already stored."""
        with self._tx() as db:
            db.executemany(
                f"INSERT INTO tasks ({', '.join(_COLUMNS)}) VALUES ({', '.join('?' * len(_COLUMNS))})",
                [_row(r) for r in recs],
            )
            self._add_events(db, events)
            if counter is not None:
                _raise(db, "task", counter)

    def save(self, rec: TaskRecord, event: TaskEvent | None) -> None:
        """One state change of ``rec``: its row, its robot's lease (held while the task is
        assigned or active) and its event, in one transaction."""
        with self._tx() as db:
            row = _row(rec)
            db.execute(
                f"UPDATE tasks SET {', '.join(f'{c}=?' for c in _COLUMNS[1:])} WHERE id=?",
                (*row[1:], rec.id),
            )
            db.execute("DELETE FROM leases WHERE task_id=?", (rec.id,))
            if rec.state in (TaskState.ASSIGNED, TaskState.ACTIVE) and rec.robot and rec.assignment:
                db.execute(
                    "INSERT OR REPLACE INTO leases VALUES (?, ?, ?, ?)",
                    (rec.robot, rec.id, rec.assignment, rec.updated_at),
                )
            if event is not None:
                self._add_events(db, [event])

    def events(self, task_id: str | None = None, limit: int = 100) -> list[TaskEvent]:
        """The latest ``limit`` events (of ``task_id``), oldest first."""
        with self._lock:
            if task_id is None:
                q = "SELECT * FROM events ORDER BY seq DESC LIMIT ?"
                rows = self._db.execute(q, (limit,)).fetchall()
            else:
                q = "SELECT * FROM events WHERE task_id=? ORDER BY seq DESC LIMIT ?"
                rows = self._db.execute(q, (task_id, limit)).fetchall()
        return [TaskEvent(*r) for r in reversed(rows)]

    def last_event_seq(self) -> int:
        with self._lock:
            row = self._db.execute("SELECT MAX(seq) FROM events").fetchone()
        return int(row[0] or 0)

    def _add_events(self, db: sqlite3.Connection, events: Sequence[TaskEvent]) -> None:
        if not events:
            return
        db.executemany(
            "INSERT INTO events VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [
                (e.seq, e.task_id, e.event, e.state, e.robot, e.assignment, e.text, e.wall, e.t)
                for e in events
            ],
        )
        self._events_since_prune += len(events)
        if self._events_since_prune >= MAX_EVENTS // 10:
            self._events_since_prune = 0
            db.execute("DELETE FROM events WHERE seq <= (SELECT MAX(seq) FROM events) - ?", (MAX_EVENTS,))

    def close(self) -> None:
        with self._lock:
            self._db.close()


def _raise(db: sqlite3.Connection, name: str, value: int) -> None:
    db.execute(
        "INSERT INTO counters VALUES (?, ?) ON CONFLICT(name) DO UPDATE SET value=max(value, excluded.value)",
        (name, int(value)),
    )


def _row(r: TaskRecord) -> tuple[Any, ...]:
    return (
        r.id,
        r.name,
        r.kind,
        r.source,
        json.dumps(r.spec),
        r.priority,
        r.only,
        r.state.value,
        r.robot,
        r.assignment,
        r.attempts,
        r.laps,
        r.steps_done,
        r.steps_total,
        r.message,
        r.submitted_by,
        r.created_at,
        r.assigned_at,
        r.started_at,
        r.ended_at,
        r.updated_at,
    )


def _record(row: Sequence[Any]) -> TaskRecord:
    d = dict(zip(_COLUMNS, row, strict=True))
    d["spec"] = json.loads(d["spec"])
    d["state"] = TaskState(d["state"])
    return TaskRecord(**d)
