"""The fleet's records on the bus: a robot's status, the coordinator's orders (tasks) and the
traffic manager's grants. Schemas and examples: ``docs/status_bus.md``."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Annotated, Final, Protocol

import msgspec
from msgspec import Meta, Struct

from fleet.messages.codec import (
    ROBOT_NAME_PATTERN,
    Buffer,
    Codec,
    Count,
    Finite,
    LongText,
    Pose,
    Poses,
    RobotName,
    Seq,
    Text,
    check_finite,
    encode,
    encode_unchecked,
    to_builtins,
)
from fleet.messages.steps import Step, StepWire, step_wire
from fleet.types import Pose2D

#: The kinds of :class:`TaskMessage`.
TASK_KINDS: Final = ("patrol", "pick", "go_to", "inspection", "charge", "park", "idle")
#: Kinds whose order carries the robot's :class:`~fleet.messages.steps.Step` list.
STEP_KINDS: Final = ("go_to", "inspection", "park")
#: At most this many steps in one order.
MAX_STEPS: Final = 1000

_ROBOT_RE = re.compile(ROBOT_NAME_PATTERN)


def check_robot_name(robot: str) -> str:
    """Return ``robot`` if it can be one key chunk (``robot3``); ValueError otherwise."""
    if not isinstance(robot, str) or not _ROBOT_RE.match(robot):
        raise ValueError(f"robot name {robot!r} cannot be a Zenoh key chunk (use letters, digits, _ . -)")
    return robot


def pose_tuple(p: Pose2D | tuple[float, float, float]) -> tuple[float, float, float]:
    """``(x, y, theta)`` as floats, of a :class:`Pose2D` (or of any 3-sequence)."""
    if isinstance(p, Pose2D):
        return (float(p.x), float(p.y), float(p.theta))
    x, y, th = p
    return (float(x), float(y), float(th))


class StatusRecord(Struct, frozen=True, tag_field="v", tag=1, omit_defaults=True, gc=False):
    """One robot's status (``fleet/<robot>/status``), also its wire form.

    ``t`` is simulated seconds; ``pose`` ``(x, y, theta)`` in the ``map`` frame or ``None``;
    ``battery`` a fraction; ``bt`` the root status name (``RUNNING``...); ``leaf`` the active
    leaf; ``mode`` a :class:`fleet.types.Mode` value; ``progress`` through the current lap in
    [0, 1]; ``seq`` increases per record; ``picks_done`` picks the robot completed since its
    agent started (optional on the wire, ``0`` when absent). Diagnostics
    (:mod:`fleet.diagnostics`): ``health`` the worst level of the robot's checks (0 OK, 1 WARN,
    2 ERROR) and ``diag`` the checks that are not OK as ``[name, level, message]`` (both
    optional on the wire: absent means all OK). ``result_id`` / ``result``: the
    last task id whose steps the robot finished and how (``succeeded`` or ``failed: <why>``;
    repeated until the next order); ``steps_done``: steps of the current task done so far.
    Acknowledgements (``docs/protocol.md``): ``epoch`` the coordinator epoch of the last order
    the agent applied, ``order_seq`` that order's sequence number, ``grant_seq`` the sequence
    number of the last grant applied. Counters: ``malformed`` payloads the status bus of the
    robot's process dropped unparsed, ``rejected`` well-formed orders and grants for this robot
    its agent ignored (not from the live coordinator, stale or out of sequence). The JSON carries ``"v": 1``.
    """

    robot: RobotName
    ns: Text
    t: Finite
    pose: Pose | None
    battery: Finite
    charging: bool
    stuck: bool
    bt: Text
    leaf: Text
    mode: Text
    task_id: Text | None
    laps: Count
    progress: Finite
    distance_m: Finite
    collisions: Count
    seq: Count
    picks_done: Count = 0
    health: Annotated[int, msgspec.Meta(ge=0, le=3)] = 0
    diag: tuple[tuple[Text, Annotated[int, msgspec.Meta(ge=0, le=3)], Text], ...] = ()
    result_id: Text | None = None
    result: LongText = ""
    steps_done: Count = 0
    epoch: Seq = 0
    order_seq: Seq = 0
    grant_seq: Seq = 0
    malformed: Count = 0
    rejected: Count = 0

    def to_json(self) -> bytes:
        """UTF-8 JSON. The record is not validated field by field (its types are the caller's
        contract; receivers validate), but a NaN or infinite number raises ValueError naming
        the field, since JSON cannot carry it."""
        data = encode_unchecked(self, "status")
        p = self.pose
        try:  # one cheap sum instead of a check per field: NaN and inf propagate
            total = self.t + self.battery + self.progress + self.distance_m
            if p is not None:
                total += p[0] + p[1] + p[2]
            finite = math.isfinite(total)
        except TypeError:
            finite = False
        if not finite:
            check_finite(self, "status")
            STATUS_CODEC.decode(data)  # a wrongly typed field: the receiver's error, here
        return data

    def to_dict(self) -> dict[str, object]:
        """The JSON object as Python values (``pose`` a list)."""
        return to_builtins(self)

    @classmethod
    def from_json(cls, data: Buffer) -> StatusRecord:
        """Parse and validate; ValueError naming the bad field (``status.battery: ...``)."""
        return STATUS_CODEC.decode(data)

    @classmethod
    def from_dict(cls, d: object) -> StatusRecord:
        """Validate a parsed JSON object; ValueError naming the bad field."""
        return STATUS_CODEC.convert(d)


STATUS_CODEC: Final = Codec(StatusRecord, "status")


class PickOrder(Struct, frozen=True):
    """Pick details of a ``pick`` task: drive to ``shelf``, stand ``dwell_s`` s, drive to ``drop``.

    Any object with ``name``, ``shelf``, ``drop`` and ``dwell_s`` (e.g.
    :class:`fleet.config.PickTask`) can be sent; a received one is a :class:`PickOrder`.
    """

    name: str
    shelf: Pose2D
    drop: Pose2D
    dwell_s: float


class PickLike(Protocol):
    """What a :class:`TaskMessage` needs of a pick (:class:`PickOrder`, ``PickTask``)."""

    @property
    def name(self) -> str: ...

    @property
    def shelf(self) -> Pose2D: ...

    @property
    def drop(self) -> Pose2D: ...

    @property
    def dwell_s(self) -> float: ...


class TaskMessage(Struct, frozen=True):
    """An order for one robot (``fleet/<robot>/task``).

    ``kind`` is ``patrol`` (``route`` name and the lap's ``poses``), ``pick`` (``pick`` set,
    and its ``steps``: shelf, dwell, drop), ``go_to`` / ``inspection`` / ``park`` (``steps``
    set, see :mod:`fleet.messages.steps`), ``charge`` (go and charge now, at ``charger``) or
    ``idle`` (``task_id`` may be ``None``). ``charger`` is the charger pose to use when low.
    ``robot`` is the addressee (filled from the key on receipt if absent). Task ids are never
    reused. ``epoch`` is the sending coordinator's epoch and ``seq`` its per-robot sequence
    number (``docs/protocol.md``): an agent applies an order from the bus only if ``epoch`` is
    the live coordinator's and ``seq`` is newer than the last one it applied.
    """

    task_id: str | None
    kind: str
    robot: str | None = None
    route: str | None = None
    poses: tuple[Pose2D, ...] = ()
    charger: Pose2D | None = None
    pick: PickLike | None = None
    steps: tuple[Step, ...] = ()
    epoch: int = 0
    seq: int = 0

    def _wire(self) -> _TaskWire:
        pk = self.pick
        return _TaskWire(
            task_id=self.task_id,
            kind=self.kind,
            robot=self.robot,
            route=self.route,
            poses=tuple(pose_tuple(p) for p in self.poses),
            charger=None if self.charger is None else pose_tuple(self.charger),
            pick=None
            if pk is None
            else _PickWire(
                name=str(getattr(pk, "name", "")),
                shelf=pose_tuple(pk.shelf),
                drop=pose_tuple(pk.drop),
                dwell_s=float(pk.dwell_s),
            ),
            steps=tuple(step_wire(st) for st in self.steps),
            epoch=self.epoch,
            seq=self.seq,
        )

    def to_dict(self) -> dict[str, object]:
        """The JSON object as Python values; absent optional fields are left out."""
        return to_builtins(self._wire())

    def to_json(self) -> bytes:
        """UTF-8 JSON; ValueError naming the field if the order is inconsistent (a patrol
        without poses, a pick without its pick, a NaN)."""
        wire = self._wire()
        wire.check("task")
        return encode(wire, "task")

    @classmethod
    def from_json(cls, data: Buffer) -> TaskMessage:
        """Parse and validate; ValueError naming the bad field (``task.poses[2]: ...``)."""
        return TASK_CODEC.decode(data).check("task").message()

    @classmethod
    def from_dict(cls, d: object) -> TaskMessage:
        """Validate a parsed JSON object; ValueError naming the bad field."""
        return TASK_CODEC.convert(d).check("task").message()


class _PickWire(Struct, frozen=True, kw_only=True):
    name: Text = ""
    shelf: Pose
    drop: Pose
    dwell_s: Finite


class _TaskWire(Struct, frozen=True, kw_only=True, omit_defaults=True, tag_field="v", tag=1):
    task_id: Text | None
    kind: Text
    robot: RobotName | None = None
    route: Text | None = None
    poses: Poses = ()
    charger: Pose | None = None
    pick: _PickWire | None = None
    steps: Annotated[tuple[StepWire, ...], Meta(max_length=MAX_STEPS)] = ()
    epoch: Seq = 0
    seq: Seq = 0

    def check(self, what: str) -> _TaskWire:
        """What the types cannot say: ids, poses and picks that each kind needs."""
        if self.kind not in TASK_KINDS:
            raise ValueError(f"{what}.kind: {self.kind!r} is not one of {', '.join(TASK_KINDS)}")
        if self.task_id is None and self.kind != "idle":
            raise ValueError(f"{what}.task_id: a {self.kind} task needs an id")
        if self.kind == "pick" and self.pick is None:
            raise ValueError(f"{what}.pick: missing (a pick task needs shelf, drop and dwell_s)")
        if self.kind == "patrol" and not self.poses:
            raise ValueError(f"{what}.poses: a patrol task needs at least one pose")
        if self.kind in STEP_KINDS and not self.steps:
            raise ValueError(f"{what}.steps: a {self.kind} task needs at least one step")
        for i, st in enumerate(self.steps):
            st.check(f"{what}.steps[{i}]")
        return self

    def message(self) -> TaskMessage:
        pk = self.pick
        return TaskMessage(
            task_id=self.task_id,
            kind=self.kind,
            robot=self.robot,
            route=self.route,
            poses=tuple(Pose2D(*p) for p in self.poses),
            charger=None if self.charger is None else Pose2D(*self.charger),
            pick=None if pk is None else PickOrder(pk.name, Pose2D(*pk.shelf), Pose2D(*pk.drop), pk.dwell_s),
            steps=tuple(st.step() for st in self.steps),
            epoch=self.epoch,
            seq=self.seq,
        )


TASK_CODEC: Final = Codec(_TaskWire, "task")


class Grant(Struct, frozen=True):
    """What one robot may drive now (``fleet/<robot>/grant``).

    ``nodes`` / ``poses``: the granted path nodes ahead of the node the robot last reached
    (``current``), in driving order, with poses facing along the path (``map`` frame). Empty
    while the robot must wait (or has no path). ``horizon`` is the absolute index in path
    ``path_id`` of the last granted node: a follower resends a goal when ``(path_id,
    horizon)`` changes. ``final``: the grant reaches the end of the path. ``alive``: false
    once the manager treats the robot as dead (it must not move). ``done``: the robot has
    reached the end of its path. Set by :class:`ReservationTraffic` (the manager leaves the
    defaults): ``task_id`` the coordinator assignment the path serves, ``purpose`` why the
    robot drives (``patrol``, ``charge``, ``charge-wait``, ``park`` or ``""``), ``laps``
    loops completed on the path for ``task_id``, ``seq`` a per-robot counter (a receiver
    ignores a grant whose ``seq`` is not newer than the last one it applied); ``epoch`` the
    sending coordinator's epoch (``docs/protocol.md``).
    JSON: :meth:`to_dict` / :meth:`from_dict`, :meth:`to_json` / :meth:`from_json`.
    A copy with changes: ``msgspec.structs.replace(grant, seq=2)``.
    """

    robot: str
    path_id: int
    horizon: int
    current: str | None
    nodes: tuple[str, ...]
    poses: tuple[Pose2D, ...]
    final: bool = False
    waiting: bool = False
    done: bool = False
    alive: bool = True
    task_id: str | None = None
    purpose: str = ""
    laps: int = 0
    seq: int = 0
    epoch: int = 0

    def _wire(self) -> _GrantWire:
        fields = msgspec.structs.asdict(self)
        fields["poses"] = tuple((p.x, p.y, p.theta) for p in self.poses)
        return _GrantWire(**fields)

    def to_dict(self) -> dict[str, object]:
        """The JSON object as Python values (``"v": 1``, poses as ``[x, y, theta]``)."""
        return to_builtins(self._wire())

    def to_json(self) -> bytes:
        """UTF-8 JSON; ValueError naming the field for a NaN or infinite pose."""
        return encode(self._wire(), "grant")

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> Grant:
        """Validate a parsed JSON object; ValueError naming the bad field."""
        return GRANT_CODEC.convert(d).grant("grant")

    @classmethod
    def from_json(cls, data: Buffer) -> Grant:
        """Parse and validate; ValueError naming the bad field (``grant.poses[1]: ...``)."""
        return GRANT_CODEC.decode(data).grant("grant")


class _GrantWire(Struct, frozen=True, tag_field="v", tag=1):
    robot: Text
    path_id: int
    horizon: int
    current: Text | None
    nodes: tuple[Text, ...]
    poses: tuple[Pose, ...]
    final: bool = False
    waiting: bool = False
    done: bool = False
    alive: bool = True
    task_id: Text | None = None
    purpose: Text = ""
    laps: Count = 0
    seq: Seq = 0
    epoch: Seq = 0

    def grant(self, what: str) -> Grant:
        if len(self.poses) != len(self.nodes):
            raise ValueError(f"{what}.poses: {len(self.nodes)} nodes but {len(self.poses)} poses")
        fields = msgspec.structs.asdict(self)
        fields["poses"] = tuple(Pose2D(*p) for p in self.poses)
        return Grant(**fields)


GRANT_CODEC: Final = Codec(_GrantWire, "grant")
