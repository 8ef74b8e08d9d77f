"""The coordinator's values: what it hears from a robot (:class:`Observation`), what it knows
about one (:class:`RobotView`), what it tells one (:class:`TaskOrder`), and its records of
work handed out (:class:`Assignment`) and taken back (:class:`Reassignment`).

Times are seconds of the fleet clock; poses are in the ``map`` frame (m, rad).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fleet.types import Mode, Pose2D, TaskKind, frozen_factory

if TYPE_CHECKING:
    from fleet.config.model import PickTask
    from fleet.messages import Step


class Reason(enum.StrEnum):
    """Why a task was taken back from its robot (:attr:`Reassignment.reason`)."""

    DEAD = "dead"
    STUCK = "stuck"
    CHARGING = "charging"
    #: its safety watchdog stopped it (localization lost, navigation server down)
    SAFETY_STOP = "safety_stop"
    #: a restarted coordinator's lease that the robot's first status did not confirm
    RESTART = "restart"
    #: the task was canceled while the robot held it
    CANCELED = "canceled"
    #: the robot did not acknowledge the order in time: re-issued under a new id
    NO_ACK = "no_ack"


REASON_DEAD = Reason.DEAD
REASON_STUCK = Reason.STUCK
REASON_CHARGING = Reason.CHARGING


@dataclass(frozen=True)
class Observation:
    """What one status record tells the coordinator about a robot.

    ``t``: the record's timestamp (s); ``pose``: map frame or ``None``; ``battery`` in [0, 1];
    ``mode``: the tree's mode, a :class:`~fleet.types.Mode` value (an unknown mode from the
    wire is kept as it came); ``task_id``: the assignment the robot is executing; ``laps``:
    laps completed for that id; ``picks_done``: picks the robot completed since its agent
    started (cumulative).
    """

    t: float
    pose: Pose2D | None
    battery: float = 1.0
    mode: str = Mode.IDLE
    stuck: bool = False
    task_id: str | None = None
    laps: int = 0
    charging: bool = False
    picks_done: int = 0
    result_id: str | None = None
    result: str = ""
    steps_done: int = 0


#: ``Observation(**fields)`` without the frozen dataclass's ``__init__`` (the very instance it
#: builds, at half the cost): one is built for every robot every period.
make_observation = frozen_factory(Observation)


@dataclass(frozen=True)
class TaskOrder:
    """A message for one robot (published on ``fleet/<robot>/task``).

    ``kind`` is :attr:`TaskKind.PATROL <fleet.types.TaskKind.PATROL>` (``route`` and
    ``poses`` set), ``PICK`` (``pick`` set: a :class:`fleet.config.model.PickTask`, and its
    ``steps``), ``GO_TO`` / ``INSPECTION`` / ``PARK`` (``steps`` set), ``CHARGE`` or ``IDLE``
    (drop any task). ``charger`` is the charger pose the robot should use when its battery
    runs low.
    """

    robot: str
    task_id: str
    kind: TaskKind
    route: str | None
    poses: tuple[Pose2D, ...]
    charger: Pose2D | None
    pick: PickTask | None = None
    steps: tuple[Step, ...] = ()


@dataclass
class Assignment:
    """One task given to ``robot`` at ``t_assigned`` under the fresh id ``task_id``.

    ``name`` is the task's name (a route's name, a pick's name) and ``kind`` its kind;
    ``poses`` the lap the robot was sent (patrols; empty for picks). ``laps`` is the highest
    lap count the robot reported for this id. ``t_completed`` is when the assignment first
    counted as completed (a patrol's first lap, a pick's drop); ``base`` the robot's
    ``picks_done`` in its first status carrying this id (picks). ``ended`` / ``end_reason``:
    when and why the task was taken back (``None`` otherwise). ``t_started``: when the
    robot's status first carried ``task_id`` (it is executing it); ``steps_done``: the steps
    it reported done; ``restored``: re-read from a durable task book by a restarted
    coordinator and not yet confirmed by the robot.
    """

    task_id: str
    name: str
    kind: TaskKind
    robot: str
    t_assigned: float
    poses: tuple[Pose2D, ...] = ()
    laps: int = 0
    t_completed: float | None = None
    base: int | None = None
    ended: float | None = None
    end_reason: str | None = None
    t_started: float | None = None
    steps_done: int = 0
    restored: bool = False

    @property
    def route(self) -> str:
        """The task's name, as reports call it (``assignments[].route``)."""
        return self.name

    @property
    def t_first_lap(self) -> float | None:
        """When a patrol's first lap was reported (the time it completed)."""
        return self.t_completed

    @property
    def completed(self) -> bool:
        """A patrol with at least one lap, a pick dropped off."""
        return self.t_completed is not None


@dataclass
class Reassignment:
    """A task (``route`` is its name: a route, a pick) taken from ``from_robot`` at ``t`` for
    ``reason`` (``dead``, ``stuck``, ``charging``). ``to_robot`` / ``new_task_id`` /
    ``t_reassigned`` are filled when it is given to another robot (``None`` while it waits)."""

    t: float
    route: str
    from_robot: str
    reason: str
    old_task_id: str
    to_robot: str | None = None
    new_task_id: str | None = None
    t_reassigned: float | None = None


@dataclass
class RobotView:
    """Everything the coordinator knows about one robot (mutable; owned by the state).

    ``alive``: it holds its liveliness token and reports; ``last_seen``: its last status (s);
    ``obs``: that status (``None`` until the first one, and after death); ``assignment``: the
    task it holds (``None``: free); ``charger``: index of its charger; ``progress_pose`` /
    ``progress_t``: where and when it last made progress; ``cooldown_until``: it is ranked last
    for new tasks until then (taken off one for being stuck); ``last_order`` / ``last_sent``:
    the last order sent and when; ``was_stuck``: its previous status said ``stuck``.
    """

    name: str
    alive: bool = True
    last_seen: float | None = None
    obs: Observation | None = None
    assignment: Assignment | None = None
    charger: int | None = None
    progress_pose: Pose2D | None = None
    progress_t: float = 0.0
    cooldown_until: float = -math.inf
    last_order: TaskOrder | None = None
    last_sent: float = -math.inf
    was_stuck: bool = False


@dataclass
class CoordinatorParams:
    """Thresholds (seconds) and the battery level below which robots go to charge."""

    stuck_reassign_s: float = 30.0
    status_timeout_s: float = 3.0
    battery_low: float = 0.25
    #: an order whose id the robot's status has not carried this long is re-issued (s)
    ack_timeout_s: float = 5.0
