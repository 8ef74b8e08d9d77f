"""Event-driven ticking: tick a robot's tree when something it reads changed, not on the clock.

The runner keeps the agents' period (``agent.tick_hz``): every period each agent still reads its
robot's state, checks its safety watchdog and reports its status, exactly as before. What the
:class:`TickScheduler` decides is whether the agent's *tree* is ticked in that period. It is,
when

* the agent has orders, a grant or a control change waiting (:meth:`RobotAgent.pending`), or its
  safety watchdog or the fleet's pause / e-stop changes what the agent does;
* a goal the tree polled changed status (or was sent and not polled yet);
* one of the robot's flags (``stuck``, ``charging``, ``localized``, ``navigation_ready``) changed;
* a condition a node declared in the tree's :class:`~fleet.wake.Wake` holds (battery below or
  at a threshold, the charge-energy line, within a distance of a point, a goal's distance
  remaining at or below a distance, a time reached) or a node asked for every period;
* the heartbeat is due (``heartbeat_s`` since the tree's last tick);
* the tree contains a node that does not keep the :mod:`fleet.wake` contract (then it is ticked
  every period).

All robots are checked at once: one :func:`fleet.navigation.query_batch` per period (the
simulator answers it from its arrays) and array comparisons against what each tree saw at its
last tick. Decisions are the clocked fleet's: a tree is ticked at the same period instants, and
a period it skips is one in which its tick would have changed nothing
(``tests/fleet/runtime/test_scheduler.py`` runs the shipped configs both ways).

``mode="clock"`` ticks every tree every period (the behaviour before this scheduler).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from fleet.navigation import GOAL_CODES, NO_GOAL, BatchNavigation, NavBatch, NavigationBackend, query_batch
from fleet.types import GoalStatus
from fleet.wake import SENT

if TYPE_CHECKING:
    from fleet.runtime.agent import RobotAgent

#: Tick modes.
MODES = ("event", "clock")

#: Default seconds between two ticks of a tree that nothing woke (the config's
#: ``agent.heartbeat_s``): a safety net only, since a tree keeping the ``fleet.wake`` contract
#: is woken by everything that changes its decisions.
HEARTBEAT_S = 10.0

#: Status code of a goal sent and not polled yet: differs from every code.
_SENT_CODE = -2

#: Slack on the threshold comparisons: a tick too early is harmless, one too late is not.
_EPS = 1e-9


class TickScheduler:
    """Which agents' trees to tick each period (see the module docstring).

    ``agents`` are the runner's agents, ``backends`` the world's backends of the same robots
    (in the same order; they answer the batch query), ``mode`` ``"event"`` or ``"clock"``.
    ``tree_ticks`` / ``periods`` count the trees ticked and the agent periods seen.
    """

    def __init__(
        self,
        agents: Sequence[RobotAgent],
        backends: Sequence[NavigationBackend],
        *,
        mode: str = "event",
        heartbeat_s: float = HEARTBEAT_S,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"tick mode must be one of {MODES}, got {mode!r}")
        if len(agents) != len(backends):
            raise ValueError(f"{len(agents)} agents but {len(backends)} backends")
        self.agents = list(agents)
        self.backends = list(backends)
        self._namespaces = [b.namespace for b in self.backends]
        servers = {id(s): s for s in (getattr(b, "batch_server", None) for b in self.backends)}
        server = next(iter(servers.values())) if len(servers) == 1 else None
        #: The world's batch query, when every backend has the same one (else query_batch loops).
        self._server = server if isinstance(server, BatchNavigation) else None
        self.mode = mode
        self.heartbeat_s = float(heartbeat_s)
        n = len(self.agents)
        self.tree_ticks = 0
        self.periods = 0
        self._index = {id(a): i for i, a in enumerate(self.agents)}
        self._always = np.ones(n, dtype=np.bool_)
        self._last = np.full(n, -math.inf)
        self._goal: list[str | None] = [None] * n
        self._seen = np.full(n, NO_GOAL, dtype=np.int8)
        self._extra: dict[int, dict[str, int]] = {}
        self._below = np.full(n, -math.inf)
        self._at_least = np.full(n, math.inf)
        self._line = np.full((n, 6), math.nan)
        self._near = np.full((n, 3), math.nan)
        self._rem_goal: list[str | None] = [None] * n
        #: Rows whose ``remaining`` goal is not their first watched goal: row -> that goal.
        self._rem_rows: dict[int, str] = {}
        self._has_goal = np.zeros(n, dtype=np.bool_)
        self._rem = np.full(n, math.nan)
        self._due = np.full(n, math.inf)
        self._flags: np.ndarray = np.zeros((n, 4), dtype=np.bool_)
        self._flags_known = np.zeros(n, dtype=np.bool_)
        self._static = np.array([mode == "event" and a.event_driven for a in self.agents], dtype=np.bool_)

    def due(self, now: float) -> np.ndarray:
        """Boolean mask of the agents whose tree should tick at ``now`` (simulated s)."""
        self.periods += 1
        n = len(self.agents)
        if n == 0 or not self._static.any():
            return np.ones(n, dtype=np.bool_)
        rem_rows = list(self._rem_rows)
        b = self._query(
            self.backends + [self.backends[i] for i in rem_rows], self._goal + list(self._rem_rows.values())
        )
        status = b.goal_status[:n].astype(np.int16)
        battery = b.battery[:n]
        x, y = b.x[:n], b.y[:n]
        flags = np.column_stack([b.stuck[:n], b.charging[:n], b.localized[:n], b.navigation_ready[:n]])
        self._flags_now = flags
        due = ~self._static | self._always | (now - self._last >= self.heartbeat_s - _EPS)
        due |= (status != self._seen) & self._has_goal
        due |= self._flags_known & (flags != self._flags).any(axis=1)
        due |= ~self._flags_known
        due |= battery < self._below + _EPS
        due |= battery >= self._at_least - _EPS
        low, cap, a, slope, cx, cy = self._line.T
        with np.errstate(invalid="ignore"):
            line = np.minimum(cap, np.maximum(low, a + slope * (np.abs(x - cx) + np.abs(y - cy))))
            due |= battery < line + _EPS
            nx, ny, nr = self._near.T
            due |= np.hypot(x - nx, y - ny) <= nr + _EPS
            rem = b.distance_remaining[:n].copy()
            for k, i in enumerate(rem_rows):
                rem[i] = b.distance_remaining[n + k]
            due |= rem <= self._rem + _EPS
        due |= self._due <= now + _EPS
        for i, extra in self._extra.items():  # trees that polled more than one goal (rare)
            if not due[i] and any(_code(self.backends[i], g) != c for g, c in extra.items()):
                due[i] = True
        # orders, a grant or a control change waiting: the agent's period ticks the tree itself
        # when it applies them (RobotAgent.period), so no pass over the agents here
        return due

    def _query(self, backends: list[NavigationBackend], goal_ids: list[str | None]) -> NavBatch:
        """One batch query (the world's own when it has one: no per-backend look-up)."""
        if self._server is None:
            return query_batch(backends, goal_ids)
        n = len(self._namespaces)
        extra = [b.namespace for b in backends[n:]]
        return self._server.query_batch(self._namespaces + extra, goal_ids)

    def ticked(self, agent: RobotAgent, now: float) -> None:
        """``agent``'s tree was just ticked at ``now``: keep what it will wait for."""
        i = self._index.get(id(agent))
        if i is None:
            return
        self.tree_ticks += 1
        self._last[i] = now
        flags = getattr(self, "_flags_now", None)
        if flags is not None:
            self._flags[i] = flags[i]
            self._flags_known[i] = True
        wake = agent.wake
        if wake is None:
            self._always[i] = True
            return
        self._always[i] = wake.always or agent.settling
        goals = list(wake.goals.items())
        self._goal[i] = goals[0][0] if goals else None
        self._has_goal[i] = bool(goals)
        self._seen[i] = _status_code(goals[0][1]) if goals else NO_GOAL
        if len(goals) > 1:
            self._extra[i] = {g: _status_code(s) for g, s in goals[1:]}
        else:
            self._extra.pop(i, None)
        self._below[i] = wake.below
        self._at_least[i] = wake.at_least
        self._line[i] = wake.line if wake.line is not None else (math.nan,) * 6
        self._near[i] = wake.near_point if wake.near_point is not None else (math.nan,) * 3
        if wake.remaining is not None:
            self._rem_goal[i], self._rem[i] = wake.remaining
        else:
            self._rem_goal[i], self._rem[i] = None, math.nan
        rem = self._rem_goal[i]
        if rem is not None and rem != self._goal[i]:
            self._rem_rows[i] = rem
        else:
            self._rem_rows.pop(i, None)
        self._due[i] = wake.due


def _status_code(status: GoalStatus | None) -> int:
    return _SENT_CODE if status is SENT or status is None else GOAL_CODES[status]


def _code(backend: NavigationBackend, goal_id: str) -> int:
    """The status code of ``goal_id`` now (read from the world's backend)."""
    try:
        return GOAL_CODES[backend.goal_state(goal_id).status]
    except KeyError:
        return NO_GOAL
