"""When a robot's behaviour tree needs its next tick: the contract between the tree's nodes and
the event-driven tick scheduler (:mod:`fleet.runtime.scheduler`).

A tick of a robot's tree is a function of what the tree reads: the robot's blackboard (changed
only by orders, grants and control states, which always cause a tick), the states of the goals
it polls, the robot's state (pose, battery, flags) and the clock. Ticking it when none of those
changed in a way the tree checks gives the same decisions as ticking it at every period of the
clock, at a fraction of the cost. While a tree ticks, its nodes say what would change their
minds in a :class:`Wake`:

* every goal the tree polls is watched automatically (the scheduler's backend wrapper records
  the status it returned; a goal sent is watched from its first status on): the tree ticks
  again when a watched goal's status differs from what it saw;
* the robot's flags (``stuck``, ``charging``, ``localized``, ``navigation_ready``) are watched
  for every robot;
* continuous values are declared by the node that compares them with a threshold:
  :meth:`Wake.battery_below`, :meth:`Wake.battery_at_least`, :meth:`Wake.battery_below_line`
  (an energy threshold that grows with the Manhattan distance to a charger),
  :meth:`Wake.near` (the robot within a distance of a point), :meth:`Wake.remaining_at_most`
  (a goal's ``distance_remaining`` feedback at or below a distance), :meth:`Wake.at` (a time
  the node waits for);
* a node that cannot say calls :meth:`Wake.every_tick`, and the tree is ticked every period.

Only trees made entirely of nodes that keep this contract (class attribute ``wake_aware =
True``, or a py_trees composite or decorator listed by the scheduler) are ticked on change;
any other tree is ticked at every period, as before. Units: meters, battery fractions,
simulated seconds.
"""

from __future__ import annotations

import math

from fleet.types import GoalStatus

#: ``Wake.goals`` value of a goal sent during the tick and not polled yet (any status differs).
SENT = None


class Wake:
    """What must happen before the next tick of one robot's tree (see the module docstring).
    The scheduler resets it before each tick; the nodes that run add to it."""

    __slots__ = ("always", "goals", "below", "at_least", "line", "near_point", "remaining", "due")

    def __init__(self) -> None:
        self.always = False
        #: Goal id -> the status the tree saw (``SENT``: sent, not polled yet).
        self.goals: dict[str, GoalStatus | None] = {}
        #: Tick when the battery is below this fraction.
        self.below = -math.inf
        #: Tick when the battery is at or above this fraction.
        self.at_least = math.inf
        #: ``(low, cap, a, b, cx, cy)``: tick when battery < min(cap, max(low, a + b * d)), d the
        #: Manhattan distance (m) from the robot to (cx, cy).
        self.line: tuple[float, float, float, float, float, float] | None = None
        #: ``(x, y, r)``: tick when the robot is within r meters of (x, y).
        self.near_point: tuple[float, float, float] | None = None
        #: ``(goal_id, r)``: tick when that goal's distance remaining is at most r meters.
        self.remaining: tuple[str, float] | None = None
        #: Tick at this simulated time.
        self.due = math.inf

    def reset(self) -> None:
        """Forget every condition (before a tick)."""
        self.always = False
        self.goals.clear()
        self.below = -math.inf
        self.at_least = math.inf
        self.line = self.near_point = self.remaining = None
        self.due = math.inf

    def every_tick(self) -> None:
        """Tick at every period (a node that cannot say what it waits for)."""
        self.always = True

    def saw_goal(self, goal_id: str, status: GoalStatus | None) -> None:
        """The tree saw goal ``goal_id`` in ``status`` (``SENT``: it was just sent)."""
        self.goals[goal_id] = status

    def battery_below(self, fraction: float) -> None:
        """Tick when the battery falls below ``fraction``."""
        self.below = max(self.below, fraction)

    def battery_at_least(self, fraction: float) -> None:
        """Tick when the battery reaches ``fraction``."""
        self.at_least = min(self.at_least, fraction)

    def battery_below_line(
        self, low: float, cap: float, a: float, b: float, charger: tuple[float, float]
    ) -> None:
        """Tick when the battery falls below ``min(cap, max(low, a + b * d))``, ``d`` the
        Manhattan distance (m) from the robot to ``charger``."""
        if self.line is not None:
            self.always = True  # one line per tree is all the scheduler keeps
        self.line = (low, cap, a, b, charger[0], charger[1])

    def near(self, x: float, y: float, radius_m: float) -> None:
        """Tick when the robot is within ``radius_m`` of ``(x, y)`` (``map`` frame)."""
        if self.near_point is not None:
            self.always = True
        self.near_point = (x, y, radius_m)

    def remaining_at_most(self, goal_id: str, distance_m: float) -> None:
        """Tick when goal ``goal_id``'s ``distance_remaining`` feedback is at most ``distance_m``."""
        if self.remaining is not None:
            self.always = True
        self.remaining = (goal_id, distance_m)

    def at(self, t: float) -> None:
        """Tick at simulated time ``t`` (or at the first period after it)."""
        self.due = min(self.due, t)


def wake_of(source: object) -> Wake | None:
    """The :class:`Wake` a node declares into: its backend's ``wake`` (the scheduler's backend
    wrapper has one), or ``None`` when the tree is not ticked on change."""
    wake = getattr(source, "wake", None)
    return wake if isinstance(wake, Wake) else None
