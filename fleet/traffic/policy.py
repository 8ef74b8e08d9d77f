"""The coordinator's traffic policy: turn each robot's wish (patrol loop, charger, parking)
into a path on the docked roadmap and hand out grants (``docs/traffic.md``)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import msgspec
import networkx as nx

from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from fleet.roadmap.graph import Roadmap
from fleet.errors import TrafficError
from fleet.messages import Grant
from fleet.traffic.manager import (
    CHARGE_PRIORITY,
    PURPOSE_CHARGE,
    PURPOSE_CHARGE_WAIT,
    PURPOSE_PARK,
    PURPOSE_PATROL,
    TrafficManager,
)
from fleet.traffic.params import TrafficParams


class ReservationTraffic:
    """A ``fleet.coordination.coordinator.TrafficPolicy`` backed by a :class:`TrafficManager`.

    It decides *where* each robot drives; the manager decides *when*:

    * ``on_assign`` gives the robot its patrol loop (the route's waypoint nodes joined by
      shortest roadmap paths, every waypoint must-visit); ``on_release`` drops it.
    * A robot whose status mode is ``charging`` is sent to the nearest charger dock that
      nobody holds or heads for, lowest battery first; if every charger is taken it waits
      at a free parking dock near the chargers (purpose ``charge-wait``) and is sent on when
      a charger frees.
    * A robot idle (no route, mode ``idle``) for ``park_idle_s`` that does not stand on a
      parking or charger dock is sent to the nearest free parking dock, so idle robots do
      not stand in aisles. A robot on a charger dock that has finished charging is moved
      to parking only when another robot waits for a charger.
    * ``cycle`` feeds every robot view's pose and liveness into the manager, runs one manager
      cycle and hands every changed grant, stamped with the robot's task id, purpose, lap
      count and a per-robot ``seq``, to ``deliver(robot, grant)``. Robots are registered the
      first time their pose is seen (a robot whose node another robot holds waits,
      unregistered and standing still, until it is free).
    * Deadlocks for the fleet report: a set of robots waiting on each other (a wait-for
      cycle) for more than ``deadlock_s``; each such set counts once while it lasts
      (:attr:`deadlocks`, episodes in :attr:`deadlock_events`).

    ``roadmap`` is the traffic roadmap (with docks, see :func:`traffic_from_config`);
    ``chargers`` / ``parking`` are its dock node names.
    """

    def __init__(
        self,
        roadmap: Roadmap,
        params: TrafficParams | None = None,
        deliver: Callable[[str, Grant], None] | None = None,
        *,
        chargers: Sequence[str] = (),
        parking: Sequence[str] = (),
        deadlock_s: float = 30.0,
        park_idle_s: float = 5.0,
    ) -> None:
        self.roadmap = roadmap
        self.manager = TrafficManager(roadmap, params)
        self.deliver = deliver
        self.chargers = list(dict.fromkeys(chargers))
        self.parking = [n for n in dict.fromkeys(parking) if n not in set(self.chargers)]
        self._parking_set = set(self.parking)
        self._charger_set = set(self.chargers)
        self.deadlock_s = float(deadlock_s)
        self.park_idle_s = float(park_idle_s)
        self.deadlocks = 0
        self.deadlock_events: list[tuple[float, tuple[str, ...]]] = []
        self._open_deadlocks: set[frozenset[str]] = set()
        self._now = 0.0
        self._pending: dict[str, list[str]] = {}
        self._task: dict[str, str | None] = {}
        self._purpose: dict[str, str] = {}
        self._target: dict[str, str] = {}
        self._idle_since: dict[str, float] = {}
        self._seq: dict[str, int] = {}
        self._coord_dead: set[str] = set()
        self._charge_wait: set[str] = set()
        self._last_dl = -math.inf
        self._charger_dist: dict[str, float] | None = None
        # grants of a later policy (a restarted coordinator) must outrank older ones at the
        # robots: seq counts up from the wall time this policy was made, in microseconds
        self._seq_base = time.time_ns() // 1000

    # -- TrafficPolicy -----------------------------------------------------------------

    def on_assign(
        self, robot: str, route: Any, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]:
        nodes = [str(n) for n in getattr(route, "nodes", ())]
        if nodes:
            self._pending[robot] = nodes
            self._task[robot] = task_id
            self._apply_pending(robot)
        return poses

    def on_release(self, robot: str) -> None:
        self._pending.pop(robot, None)
        self._task[robot] = None
        if self._purpose.get(robot) == PURPOSE_PATROL:
            self._purpose.pop(robot, None)
        if robot in self.manager.robots and self.manager.is_alive(robot):
            self.manager.clear_path(robot, self._now)

    def waiting(self, robot: str) -> bool:
        """True while ``robot`` stands still because the manager has not granted it more
        path, for a live robot ahead (so the coordinator must not call it stuck). A robot
        held up by a dead robot is not "waiting": the coordinator's stuck rule then gives its
        route to a robot that can reach it."""
        m = self.manager
        if robot not in m.robots:
            return robot in self._pending or robot in self._task and self._task[robot] is not None
        if robot not in m.waiting():
            return False
        return not any(b in m.robots and not m.is_alive(b) for b in m.blockers(robot))

    def cycle(self, now: float, robots: Mapping[str, Any]) -> Sequence[Any]:
        self._now = now
        m = self.manager
        requests: list[tuple[float, str]] = []
        for name, v in robots.items():
            obs = getattr(v, "obs", None)
            pose = getattr(obs, "pose", None) if obs is not None else None
            alive = bool(getattr(v, "alive", True))
            if name not in m.robots:
                if pose is None or not alive:
                    continue
                try:
                    m.add_robot(name, pose, now)
                except TrafficError:
                    continue  # its node is held: it stays put, unregistered, until it is free
            if not alive:
                if m.is_alive(name):
                    # its agent is gone but the robot may still drive its last goal: it
                    # keeps its whole grant
                    m.declare_dead(name, now, "coordinator: dead", keep_grant=True)
                self._coord_dead.add(name)
                self._purpose.pop(name, None)
                continue
            if name in self._coord_dead:
                self._coord_dead.discard(name)
                m.declare_alive(name, now)
            if pose is not None:
                m.update(name, pose, now)
            if name in self._pending:
                self._apply_pending(name)
            self._errands(name, v, obs, now, requests)
        self._serve_chargers(requests)
        changed = m.cycle(now)
        self._count_deadlocks(now)
        if self.deliver is not None:
            for name in sorted(changed):
                self.deliver(name, self.grant(name))
        return ()

    # -- queries -----------------------------------------------------------------------

    def grant(self, robot: str) -> Grant:
        """The robot's current grant, stamped with its task, purpose, laps and a new ``seq``."""
        g = self.manager.grant(robot)
        seq = self._seq.get(robot, self._seq_base) + 1
        self._seq[robot] = seq
        purpose = self._purpose.get(robot, "")
        task = self._task.get(robot) if purpose == PURPOSE_PATROL else None
        laps = self.manager.laps(robot) if purpose == PURPOSE_PATROL else 0
        return msgspec.structs.replace(g, task_id=task, purpose=purpose, laps=laps, seq=seq)

    def purpose(self, robot: str) -> str:
        return self._purpose.get(robot, "")

    def mean_wait_s(self, now: float) -> float:
        return self.manager.mean_wait_s(now)

    # -- internals ---------------------------------------------------------------------

    def _set_path(
        self, robot: str, nodes: list[str], purpose: str, must: list[int] | None = None, loop: bool = False
    ) -> None:
        m = self.manager
        if not m.is_alive(robot):
            m.declare_alive(robot, self._now)  # e.g. stalled earlier: a new errand revives it
        m.set_path(robot, nodes, self._now, must_visit=must, loop=loop)
        self._purpose[robot] = purpose

    def _apply_pending(self, robot: str) -> None:
        m = self.manager
        if robot in m.robots:
            m.set_priority(robot, 0.0)
        nodes = self._pending.get(robot)
        if nodes is None or robot not in m.robots or robot in self._coord_dead:
            return
        del self._pending[robot]
        self._target.pop(robot, None)
        self._charge_wait.discard(robot)
        loop = self.roadmap.expand_route(nodes, closed=True)
        wps = set(nodes)
        if len(loop) < 2:
            self._set_path(robot, loop, PURPOSE_PATROL)
        else:
            self._set_path(
                robot, loop, PURPOSE_PATROL, must=[i for i, n in enumerate(loop) if n in wps], loop=True
            )

    def _errands(self, name: str, v: Any, obs: Any, now: float, requests: list[tuple[float, str]]) -> None:
        """Charging and parking trips (see the class docstring). Robots that need a charger
        are collected in ``requests`` as ``(battery, robot)``: :meth:`_serve_chargers`."""
        mode = getattr(obs, "mode", None) if obs is not None else None
        purpose = self._purpose.get(name, "")
        target = self._target.get(name)
        if target is not None and self.manager.holder(target) not in (None, name):
            # another robot stepped onto the dock this robot heads for (e.g. to let a third
            # pass): choose another dock rather than wait for it, head-on on a dead-end spur
            self._target.pop(name, None)
            if purpose in (PURPOSE_CHARGE, PURPOSE_CHARGE_WAIT):
                self._purpose.pop(name, None)
                self._charge_wait.discard(name)
                purpose = ""
            elif purpose == PURPOSE_PARK:
                self._go(name, self._free_dock(name, self.parking), PURPOSE_PARK)
                return
        if mode == "charging":
            self._idle_since.pop(name, None)
            if purpose != PURPOSE_CHARGE:
                requests.append((float(getattr(obs, "battery", 0.0)), name))
            return
        if mode != "idle" or getattr(v, "assignment", None) is not None or name in self._pending:
            self._idle_since.pop(name, None)
            return
        if purpose in (PURPOSE_CHARGE, PURPOSE_CHARGE_WAIT):
            self.manager.set_priority(name, 0.0)
            self._purpose.pop(name, None)  # charged: now simply idle where it stands
            self._target.pop(name, None)
            self._charge_wait.discard(name)
            purpose = ""
        since = self._idle_since.setdefault(name, now)
        if purpose == PURPOSE_PARK or now - since < self.park_idle_s:
            return
        path = self.manager.path(name)
        here = path[0] if path else None
        if here in self._parking_set:
            return
        if here in self._charger_set and not self._charge_wait:
            return
        self._go(name, self._free_dock(name, self.parking), PURPOSE_PARK)

    def _serve_chargers(self, requests: list[tuple[float, str]]) -> None:
        """Free chargers go to the robots with the lowest battery first; the others wait on a
        free parking dock near the chargers (once; they stay there until a charger frees)."""
        if not requests:
            return
        for battery, name in sorted(requests):
            # a robot short of energy goes first at intersections and is never the one to yield
            self.manager.set_priority(name, CHARGE_PRIORITY * (2.0 - battery))
            node = self._free_dock(name, self.chargers)
            if node is not None:
                self._go(name, node, PURPOSE_CHARGE)
            elif self._purpose.get(name) != PURPOSE_CHARGE_WAIT:
                self._go(name, self._free_dock(name, self.parking, self._to_charger()), PURPOSE_CHARGE_WAIT)

    def _to_charger(self) -> dict[str, float]:
        """Roadmap distance (m) from every node to its nearest charger dock (cached)."""
        if self._charger_dist is None:
            self._charger_dist = (
                dict(
                    nx.multi_source_dijkstra_path_length(
                        self.roadmap.graph, set(self.chargers), weight="length"
                    )
                )
                if self.chargers
                else {}
            )
        return self._charger_dist

    def _go(self, name: str, node: str | None, purpose: str) -> bool:
        if node is None:
            return False
        self._target[name] = node
        if purpose == PURPOSE_CHARGE_WAIT:
            self._charge_wait.add(name)
        else:
            self._charge_wait.discard(name)
        self._set_path(name, [node], purpose)
        return True

    def _free_dock(
        self, robot: str, docks: Sequence[str], first: Mapping[str, float] | None = None
    ) -> str | None:
        """The dock nearest ``robot`` (roadmap distance; with ``first``, the dock of least
        ``first[dock]``, then nearest) that nobody else holds or heads for."""
        m = self.manager
        taken = {n for r, n in self._target.items() if r != robot}
        free = [d for d in docks if m.holder(d) in (None, robot) and d not in taken]
        if not free:
            return None
        path = m.path(robot)
        here = path[0] if path else self.roadmap.nearest_node(*m.node_pos(free[0]))
        dist = nx.single_source_dijkstra_path_length(self.roadmap.graph, here, weight="length")
        if first is None:
            return min(free, key=lambda d: (dist.get(d, math.inf), d))
        return min(free, key=lambda d: (round(first.get(d, math.inf), 1), dist.get(d, math.inf), d))

    def _count_deadlocks(self, now: float) -> None:
        if now - self._last_dl < self.manager.params.detect_period_s:
            return
        self._last_dl = now
        current = set(self.manager.deadlocked(now, self.deadlock_s))
        for c in current - self._open_deadlocks:
            self.deadlocks += 1
            self.deadlock_events.append((now, tuple(sorted(c))))
        self._open_deadlocks = current


def traffic_from_config(
    config: FleetConfig, deliver: Callable[[str, Grant], None] | None = None
) -> ReservationTraffic:
    """The :class:`ReservationTraffic` of a fleet config: its roadmap with the chargers,
    parking spots and robot start poses joined as docks (:func:`fleet.roadmap.docks.add_docks`),
    :class:`TrafficParams` from ``robot_model.radius`` and the ``traffic`` section. Raises
    :class:`~fleet.errors.ConfigError` (field ``traffic``) if a dock cannot be joined."""
    from fleet.errors import ConfigError, DockError
    from fleet.roadmap.docks import add_docks
    from fleet.roadmap.graph import Roadmap

    ts = config.traffic
    params = TrafficParams(
        robot_radius=config.sim.model.radius,
        horizon_m=ts.horizon_m,
        stall_timeout_s=ts.stall_timeout_s,
    )
    docks: list[tuple[str, Pose2D]] = [(f"charger:{c.name}", c.pose) for c in config.chargers]
    docks += [(f"park:{i}", p) for i, p in enumerate(config.parking)]
    docks += [(f"start:{r.name}", r.start) for r in config.robots]
    try:
        g, node_of = add_docks(
            config.roadmap.graph, docks, params.clearance, config.grid, params.robot_radius
        )
    except DockError as e:
        raise ConfigError(str(config.path), "traffic", str(e)) from None
    chargers = [node_of[f"charger:{c.name}"] for c in config.chargers]
    # idle robots park only on docks (a start pose on a roadmap node is no parking spot)
    parking = [
        node_of[label]
        for label, _ in docks
        if not label.startswith("charger:") and g.nodes[node_of[label]].get("dock")
    ]
    return ReservationTraffic(
        Roadmap.from_graph(g),
        params,
        deliver,
        chargers=chargers,
        parking=parking,
        deadlock_s=ts.deadlock_s,
        park_idle_s=ts.park_idle_s,
    )
