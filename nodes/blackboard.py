"""Per-robot blackboards: every robot's keys live under its own namespace.

py_trees keeps one process-global key-value store, so 1000 robots in one process would
share keys if they used plain names. Every key of a robot is therefore stored under the
robot's namespace: ``/robot1/route``, ``/robot1/laps`` ... (see ``docs/architecture.md``).

Keys written by the agent and read by the tree:

* ``route``: ``tuple[Pose2D, ...] | None`` the patrol route (looped).
* ``task_id``: ``str | None`` id of the current assignment.
* ``pick``: ``Pick | None`` (``shelf``, ``dwell_s``, ``drop``: a ``fleet.config.PickTask`` or
  a received ``fleet.messages.PickOrder``) for the picking tree.
* ``charger``: ``Pose2D | None`` the charger to use when the battery is low.
* ``charger_sites``: ``tuple[Pose2D, ...]`` every charger a traffic policy may send the robot
  to instead (written once; empty: the battery guard measures its trip to ``charger`` only,
  see :class:`nodes.trees.ChargeThreshold`).
* ``grant``: ``fleet.messages.Grant | None`` the robot's latest traffic grant (only with
  traffic management; see ``docs/traffic.md``).
* ``steps``: ``tuple[fleet.messages.Step, ...] | None`` the steps of a go_to, pick,
  inspection or park task (``nodes/steps.py``); ``task_kind``: ``str | None`` the kind of
  the current task; ``charge_now``: ``bool`` a charge task (go and charge now).

Keys written by the tree and read by the agent:

* ``laps``: ``int`` completed laps of the current route; ``lap_task_id``: the task id they
  count for.
* ``active_leaf``: ``str`` name of the action leaf that is RUNNING (or last ran).
* ``mode``: a :class:`fleet.types.Mode` (``idle``, ``patrol``, ``charging``, ``recovery``,
  ``picking``; a ``StrEnum``, so it equals its string).
* ``route_progress``: ``float`` in [0, 1] through the current lap.
* ``picks_done``: ``int``.
* ``step_index``: ``int`` steps of the current task done; ``steps_task_id``: the task id it
  counts for.
* ``result_id`` / ``result``: the last task the tree finished and how (``succeeded`` or
  ``failed: <why>``).

Extra keys of this package (not part of the agent contract, for status and debugging):

* ``active_goal``: ``str | None`` id of the goal the tree has outstanding on the backend.
  A leaf that starts a goal first cancels this one, so a preempted goal ends CANCELED.
* ``last_error``: ``str`` the last failure message of an action leaf (``""`` if none).

:class:`RobotKeys` lists every key with its type; :func:`read_key` returns typed readers.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Literal, Protocol, TypedDict, overload

import py_trees
from py_trees.blackboard import Blackboard, Client

from fleet.types import Mode, Pose2D

if TYPE_CHECKING:
    from fleet.messages import Grant, Step


class Pick(Protocol):
    """What the picking tree reads from the blackboard ``pick``: drive to ``shelf`` (``map``),
    stand ``dwell_s`` seconds, drive to ``drop``."""

    @property
    def shelf(self) -> Pose2D: ...

    @property
    def drop(self) -> Pose2D: ...

    @property
    def dwell_s(self) -> float: ...


class RobotKeys(TypedDict):
    """Every key of a robot's blackboard and the type of its value (see the module
    docstring for who writes it)."""

    route: tuple[Pose2D, ...] | None
    task_id: str | None
    pick: Pick | None
    charger: Pose2D | None
    charger_sites: tuple[Pose2D, ...]
    grant: Grant | None
    laps: int
    lap_task_id: str | None
    active_leaf: str
    mode: Mode
    route_progress: float
    picks_done: int
    steps: tuple[Step, ...] | None
    task_kind: str | None
    charge_now: bool
    step_index: int
    steps_task_id: str | None
    result_id: str | None
    result: str
    active_goal: str | None
    last_error: str


#: Every key with its default.
DEFAULTS: RobotKeys = {
    "route": None,
    "task_id": None,
    "pick": None,
    "charger": None,
    "charger_sites": (),
    "grant": None,
    "laps": 0,
    "lap_task_id": None,
    "active_leaf": "",
    "mode": Mode.IDLE,
    "route_progress": 0.0,
    "picks_done": 0,
    "steps": None,
    "task_kind": None,
    "charge_now": False,
    "step_index": 0,
    "steps_task_id": None,
    "result_id": None,
    "result": "",
    "active_goal": None,
    "last_error": "",
}
#: Keys the agent writes and the tree reads.
INPUT_KEYS = (
    "route",
    "task_id",
    "pick",
    "charger",
    "charger_sites",
    "grant",
    "steps",
    "task_kind",
    "charge_now",
)
#: Keys the tree writes and the agent reads.
OUTPUT_KEYS = (
    "laps",
    "lap_task_id",
    "active_leaf",
    "mode",
    "route_progress",
    "picks_done",
    "step_index",
    "steps_task_id",
    "result_id",
    "result",
)
#: Keys private to this package (see the module docstring).
INTERNAL_KEYS = ("active_goal", "last_error")


def normalize_namespace(namespace: str) -> str:
    """Return ``namespace`` with exactly one leading ``/`` and no trailing ``/``
    (``"robot1"`` -> ``"/robot1"``). Raises ``ValueError`` for an empty namespace: a robot
    must never write to the root of the shared blackboard."""
    ns = "/" + namespace.strip().strip("/")
    if ns == "/":
        raise ValueError("a robot blackboard needs a non-empty namespace such as '/robot1'")
    return ns


def key_path(namespace: str, key: str) -> str:
    """Absolute blackboard name of ``key`` for the robot ``namespace`` (``/robot1/laps``)."""
    return f"{normalize_namespace(namespace)}/{key}"


def ensure_defaults(namespace: str) -> None:
    """Write the default of every key in :data:`DEFAULTS` that does not exist yet under
    ``namespace``; existing values are kept."""
    ns = normalize_namespace(namespace)
    for key, value in DEFAULTS.items():
        name = f"{ns}/{key}"
        if name not in Blackboard.storage:
            Blackboard.storage[name] = value


def robot_blackboard(namespace: str, name: str | None = None, keys: Iterable[str] | None = None) -> Client:
    """A blackboard client for the robot ``namespace`` with read/write access to ``keys``
    (default: every key in :data:`DEFAULTS`), addressed by their short names
    (``bb.laps``). Missing keys get their defaults; existing values are kept, so any number
    of clients (the agent's, each leaf's) can be created for the same robot.

    Args:
        namespace: the robot namespace, e.g. ``"/robot1"`` (a leading ``/`` is added).
        name: the client's display name (default ``"<namespace>"``).
        keys: the keys to register; unknown keys are allowed (they get no default).
    """
    ns = normalize_namespace(namespace)
    client = Client(name=name or ns, namespace=ns)
    for key in DEFAULTS if keys is None else keys:
        client.register_key(key=key, access=py_trees.common.Access.WRITE)
    ensure_defaults(ns)
    return client


@overload
def read_key(namespace: str, key: Literal["route"]) -> Callable[[], tuple[Pose2D, ...] | None]: ...
@overload
def read_key(namespace: str, key: Literal["charger"]) -> Callable[[], Pose2D | None]: ...
@overload
def read_key(namespace: str, key: Literal["charger_sites"]) -> Callable[[], tuple[Pose2D, ...]]: ...
@overload
def read_key(namespace: str, key: Literal["pick"]) -> Callable[[], Pick | None]: ...
@overload
def read_key(
    namespace: str, key: Literal["task_id", "lap_task_id", "active_goal"]
) -> Callable[[], str | None]: ...
@overload
def read_key(namespace: str, key: str) -> Callable[[], object]: ...
def read_key(namespace: str, key: str) -> Callable[[], object]:
    """A callable that returns the current value of ``key`` of robot ``namespace`` (or its
    default if it was never written), typed after :class:`RobotKeys`. Use it as the goal
    source of a leaf, e.g. ``NavigateToPoseAction(backend, read_key("/robot1", "charger"))``."""
    name = key_path(namespace, key)
    default = DEFAULTS.get(key)
    storage = Blackboard.storage

    def get() -> object:
        return storage.get(name, default)

    get.__name__ = f"read_key({name!r})"
    return get


def clear_robot_blackboard(namespace: str) -> None:
    """Remove every stored key under ``namespace`` (e.g. when a robot leaves the fleet).
    Clients stay registered; reading a key through them afterwards raises ``KeyError``
    until :func:`ensure_defaults` is called again. One pass over the whole blackboard: to
    clear many robots, :func:`clear_robot_blackboards` does it in one pass for all."""
    prefix = normalize_namespace(namespace) + "/"
    for name in [k for k in Blackboard.storage if k.startswith(prefix)]:
        del Blackboard.storage[name]


def clear_robot_blackboards(namespaces: Iterable[str]) -> None:
    """:func:`clear_robot_blackboard` for every one of ``namespaces``, in one pass over the
    blackboard (a fleet of thousands of robots would otherwise scan it once per robot)."""
    by_head: dict[str, list[str]] = {}  # "/robot1/" -> the prefixes under it ("/robot1/arm/")
    for ns in namespaces:
        prefix = normalize_namespace(ns) + "/"
        by_head.setdefault(prefix[: prefix.index("/", 1) + 1], []).append(prefix)
    doomed = []
    for k in Blackboard.storage:
        under = by_head.get(k[: k.find("/", 1) + 1])
        if under is not None and any(k.startswith(p) for p in under):
            doomed.append(k)
    for name in doomed:
        del Blackboard.storage[name]
