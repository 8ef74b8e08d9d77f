"""The robot side of traffic management: turn the latest :class:`~fleet.messages.Grant` into
``NavigateThroughPoses`` goals on any :class:`~fleet.navigation.NavigationBackend`."""

from __future__ import annotations

import enum
import math
from typing import TYPE_CHECKING

from fleet.messages import Grant
from fleet.types import GoalState, GoalStatus, NavigateThroughPoses, Pose2D
from fleet.wake import wake_of

if TYPE_CHECKING:
    from fleet.navigation import NavigationBackend


class FollowerStatus(enum.Enum):
    """What a :class:`TrafficFollower` is doing."""

    IDLE = "idle"  # no grant, or no path
    DRIVING = "driving"  # a goal to the granted horizon is executing
    WAITING = "waiting"  # standing at the end of its grant, waiting for more
    ARRIVED = "arrived"  # the grant was final and the robot reached it
    STOPPED = "stopped"  # the manager treats the robot as dead: goals canceled


class TrafficFollower:
    """Drives one robot through :class:`Grant` s on any :class:`NavigationBackend`.

    Call :meth:`apply` with the robot's latest grant every tick (it is idempotent). It sends
    ``NavigateThroughPoses`` through the granted poses only, extends the goal (by preempting
    it with a longer one) once the robot is within ``refresh_m`` of the goal's end or stopped,
    sends a shorter goal at once if the grant shrank (a new path), and cancels the goal when
    the manager declares the robot dead. Leading poses the robot already stands within
    ``skip_m`` of are dropped so that a resent goal does not make it turn back. A goal that
    ends ABORTED is resent after ``retry_s`` (``now`` is passed in).
    """

    def __init__(
        self, backend: NavigationBackend, refresh_m: float = 2.5, skip_m: float = 0.35, retry_s: float = 1.0
    ) -> None:
        self.backend = backend
        self.refresh_m = refresh_m
        self.skip_m = skip_m
        self.retry_s = retry_s
        self.goal_id: str | None = None
        self.sent: tuple[int, int] | None = None  # (path_id, horizon) of the goal sent
        self.sent_end: Pose2D | None = None
        self.goals_sent = 0
        self._last_send = -math.inf
        self.status = FollowerStatus.IDLE

    def apply(self, grant: Grant | None, now: float = 0.0) -> FollowerStatus:
        """Act on ``grant`` (see the class docstring); returns the follower's status."""
        b = self.backend
        if grant is None or not grant.alive:
            self._cancel()
            self.status = FollowerStatus.STOPPED if grant is not None else FollowerStatus.IDLE
            return self.status
        state = b.goal_state(self.goal_id) if self.goal_id is not None else None
        active = state is not None and not state.status.terminal
        if not grant.nodes:
            if self.sent is not None and self.sent[0] != grant.path_id and active:
                self._cancel()  # a new path that starts where the robot stands
                active = False
            if active:
                self.status = FollowerStatus.DRIVING
            elif grant.done:
                self.status = FollowerStatus.ARRIVED
            else:
                self.status = FollowerStatus.WAITING if grant.waiting else FollowerStatus.IDLE
            return self.status
        n = self._leg_length(grant)
        key = (grant.path_id, grant.horizon - len(grant.nodes) + n)
        if key == self.sent:
            if active:
                self.status = FollowerStatus.DRIVING
                return self.status
            if state is not None and state.status is GoalStatus.SUCCEEDED:
                self.status = (
                    FollowerStatus.ARRIVED
                    if grant.final and n == len(grant.nodes)
                    else FollowerStatus.WAITING
                )
                return self.status
            if now - self._last_send < self.retry_s:
                wake = wake_of(b)
                if wake is not None:
                    wake.at(self._last_send + self.retry_s)
                self.status = FollowerStatus.WAITING
                return self.status
            # aborted or canceled under us: send again
        elif active and self.sent is not None and self.sent[0] == grant.path_id and key[1] > self.sent[1]:
            pose = b.robot_state().pose
            end = self.sent_end
            if (
                pose is not None
                and end is not None
                and pose.distance_to(end) > self.refresh_m
                and self._ahead_ok(state)
            ):
                wake = wake_of(b)
                if wake is not None and self.goal_id is not None:  # when to extend the goal
                    wake.near(end.x, end.y, self.refresh_m)
                    wake.remaining_at_most(self.goal_id, self.refresh_m)
                self.status = FollowerStatus.DRIVING
                return self.status
        self._send(grant, n, key, now)
        self.status = FollowerStatus.DRIVING
        return self.status

    @staticmethod
    def _leg_length(grant: Grant) -> int:
        """How many of the granted poses one goal may take: up to the first turn-back (a pose
        where the path reverses onto where it came from), because a navigation stack checks
        only the final pose and would call a goal that ends where it started reached."""
        nodes = (grant.current,) + grant.nodes if grant.current is not None else grant.nodes
        off = 1 if grant.current is not None else 0
        for k in range(1, len(nodes) - 1):
            if nodes[k + 1] == nodes[k - 1] or nodes[k + 1] == nodes[k]:
                return k + 1 - off if k + 1 - off > 0 else 1
        return len(grant.nodes)

    def _ahead_ok(self, state: GoalState | None) -> bool:
        """Keep driving the old goal only while the robot still has some way to go in it
        (more than ``refresh_m`` remaining, or no feedback on it)."""
        rem = state.feedback.distance_remaining_m if state is not None else None
        return rem is None or rem > self.refresh_m

    def _send(self, grant: Grant, n: int, key: tuple[int, int], now: float) -> None:
        poses = list(grant.poses[:n])
        pose = self.backend.robot_state().pose
        if pose is not None:
            while len(poses) > 1 and pose.distance_to(poses[0]) <= self.skip_m:
                poses.pop(0)
        self.goal_id = self.backend.send_goal(NavigateThroughPoses(tuple(poses)))
        self.sent = key
        self.sent_end = poses[-1]
        self.goals_sent += 1
        self._last_send = now

    def _cancel(self) -> None:
        if self.goal_id is not None:
            self.backend.cancel_goal(self.goal_id)
        self.sent = None
