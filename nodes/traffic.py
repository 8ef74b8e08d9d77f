"""The traffic-managed robot's leaf: drive where the fleet's traffic manager allows.

With traffic management (``docs/traffic.md``) a robot never plans its own way along the
roadmap. The coordinator's :class:`~fleet.traffic.policy.ReservationTraffic` decides where it
goes (its patrol loop, a charger, a parking spot) and its
:class:`~fleet.traffic.manager.TrafficManager` hands out, as a :class:`~fleet.messages.Grant` on the
robot's blackboard key ``grant``, the part of that way the robot may drive now.
:class:`FollowGrant` turns grants into navigation goals with a
:class:`~fleet.traffic.follower.TrafficFollower`.
"""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from fleet.messages import Grant
from fleet.navigation import Clock, NavigationBackend
from fleet.traffic.follower import FollowerStatus, TrafficFollower
from fleet.traffic.purpose import Purpose
from fleet.types import Mode
from nodes.blackboard import robot_blackboard


class FollowGrant(py_trees.behaviour.Behaviour):
    """Follow the robot's traffic grant (blackboard ``grant``) on its backend.

    ``initialise`` cancels a goal another leaf of the robot left outstanding (blackboard
    ``active_goal``), starts a fresh :class:`~fleet.traffic.follower.TrafficFollower` and writes
    ``mode`` and ``active_leaf``. ``update`` applies the latest grant (sending, extending or
    canceling ``NavigateThroughPoses`` goals through the granted poses only) and returns:

    * SUCCESS when ``purpose`` is given, the grant has that purpose and the robot has
      reached its end (e.g. ``purpose=Purpose.CHARGE``: standing on the charger it was
      sent to);
    * RUNNING otherwise: while driving, while waiting for the manager to grant more, while
      no grant has arrived yet, and while the manager treats the robot as stopped (its goal
      is canceled, it stands still). A leaf without ``purpose`` never finishes.

    With ``count_laps`` (the patrol leaf), the grant's lap count is written to ``laps``
    and ``lap_task_id`` when the grant's ``task_id`` is the blackboard ``task_id``.
    ``terminate`` cancels the executing goal only when the leaf was RUNNING.
    """

    #: The grant is blackboard; the follower declares what else it waits for (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        clock: Clock,
        *,
        mode: Mode,
        purpose: Purpose | None = None,
        count_laps: bool = False,
        name: str = "FollowGrant",
    ) -> None:
        super().__init__(name=name)
        self.backend = backend
        self.clock = clock
        self.mode = mode
        self.purpose = purpose
        self.count_laps = count_laps
        self.bb = robot_blackboard(
            backend.namespace,
            name=name,
            keys=("grant", "task_id", "laps", "lap_task_id", "mode", "active_leaf", "active_goal"),
        )
        self.blackboards.append(self.bb)
        self.follower = TrafficFollower(backend)

    def initialise(self) -> None:
        bb = self.bb
        other = bb.active_goal
        if other is not None:
            self.backend.cancel_goal(other)
            bb.active_goal = None
        self.follower = TrafficFollower(self.backend)
        bb.mode = self.mode
        bb.active_leaf = self.name

    def update(self) -> Status:
        bb = self.bb
        g: Grant | None = bb.grant
        st = self.follower.apply(g, self.clock.now())
        bb.active_goal = self.follower.goal_id if st is FollowerStatus.DRIVING else None
        if self.count_laps and g is not None and g.task_id is not None and g.task_id == bb.task_id:
            if bb.lap_task_id != g.task_id:
                bb.lap_task_id, bb.laps = g.task_id, 0
            bb.laps = max(int(bb.laps), int(g.laps))
        self.feedback_message = st.value
        if (
            self.purpose is not None
            and st is FollowerStatus.ARRIVED
            and g is not None
            and g.purpose == self.purpose
        ):
            return Status.SUCCESS
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if self.status == Status.RUNNING and new_status == Status.INVALID:
            self.follower.apply(None)  # cancels the executing goal
            if self.bb.active_goal is not None:
                self.bb.active_goal = None
