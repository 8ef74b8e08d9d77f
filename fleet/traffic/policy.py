"""The coordinator's traffic policy: turn each robot's wish (patrol loop, charger, parking)
into a path on the docked roadmap and hand out grants (``docs/traffic.md``)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import msgspec

from fleet.errors import ConfigError, DockError, TrafficError
from fleet.messages import Grant
from fleet.roadmap.cells import split_cells
from fleet.roadmap.docks import add_docks
from fleet.roadmap.graph import Roadmap
from fleet.traffic.errands import Errands
from fleet.traffic.manager import TrafficManager
from fleet.traffic.params import TrafficParams
from fleet.traffic.purpose import Purpose
from fleet.traffic.views import RobotViewLike, RouteLike
from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from fleet.robots import BatteryModel

#: Hands a robot's changed grant to it: ``deliver(robot, grant)``.
Deliver = Callable[[str, Grant], None]

#: At most this many deadlock episodes stay in :attr:`ReservationTraffic.deadlock_events`
#: (the older half is dropped when it is exceeded; :attr:`ReservationTraffic.deadlocks`
#: keeps counting).
MAX_DEADLOCK_EVENTS = 2000

#: Purposes of the errands (trips to a dock) that may turn back or drive against the flow.
ERRANDS = (Purpose.CHARGE, Purpose.CHARGE_WAIT, Purpose.PARK)


class ReservationTraffic:
    """A ``fleet.coordination`` ``TrafficPolicy`` backed by a :class:`TrafficManager`.

    It decides *where* each robot drives; the manager decides *when*:

    * ``on_assign`` gives the robot its patrol loop (the route's waypoint nodes joined by
      shortest roadmap paths, every waypoint must-visit); ``on_release`` drops it.
    * Robots without a patrol run errands (:class:`~fleet.traffic.errands.Errands`): a robot
      whose status mode is ``charging`` goes to a charger dock (or waits for one on a parking
      dock, purpose ``charge-wait``), a robot idle for ``park_idle_s`` off the docks goes to
      a parking dock.
    * ``cycle`` feeds every robot view's pose and liveness into the manager, runs one manager
      cycle and hands every changed grant, stamped with the robot's task id, purpose, lap
      count and a per-robot ``seq``, to ``deliver(robot, grant)``. Robots are registered the
      first time their pose is seen (a robot whose node another robot holds waits,
      unregistered and standing still, until it is free). A robot whose view is not
      ``alive`` is declared dead keeping its whole grant (it may still drive its last goal);
      ``dead_release_s`` later it keeps only the node it stands on and the routes of the
      others across its old grant are replanned.
    * Deadlocks for the fleet report: a set of robots waiting on each other (a wait-for
      cycle) for more than ``deadlock_s``; each such set counts once while it lasts
      (:attr:`deadlocks`, episodes in :attr:`deadlock_events`, bounded by
      :data:`MAX_DEADLOCK_EVENTS`).

    ``roadmap`` is the traffic roadmap (with docks, see :func:`traffic_from_config`);
    ``chargers`` / ``parking`` are its dock node names. ``deliver`` may be set later (the
    coordinator sets it when it is ``None``). ``battery``: the fleet's battery model, for
    the charging errands' energy margins (``TrafficParams.charge_margin_priority``).
    """

    def __init__(
        self,
        roadmap: Roadmap,
        params: TrafficParams | None = None,
        deliver: Deliver | None = None,
        *,
        chargers: Sequence[str] = (),
        parking: Sequence[str] = (),
        deadlock_s: float = 30.0,
        park_idle_s: float = 5.0,
        dead_release_s: float = 10.0,
        battery: BatteryModel | None = None,
    ) -> None:
        self.roadmap = roadmap
        self.manager = TrafficManager(roadmap, params)
        self.deliver = deliver
        self.chargers = list(dict.fromkeys(chargers))
        self.parking = [n for n in dict.fromkeys(parking) if n not in set(self.chargers)]
        self.deadlock_s = float(deadlock_s)
        self.park_idle_s = float(park_idle_s)
        self.dead_release_s = float(dead_release_s)
        self.deadlocks = 0
        self.deadlock_events: list[tuple[float, tuple[str, ...]]] = []
        self._open_deadlocks: set[frozenset[str]] = set()
        self._now = 0.0
        self._pending: dict[str, list[str]] = {}
        self._task: dict[str, str | None] = {}
        self._purpose: dict[str, Purpose] = {}
        self._seq: dict[str, int] = {}
        self._coord_dead: set[str] = set()
        self._once: set[str] = set()  # robots whose pending route is driven once (a task)
        #: When each robot the coordinator lost was declared dead (until it is released).
        self._dead_since: dict[str, float] = {}
        self._last_dl = -math.inf
        self.errands = Errands(
            self.manager,
            roadmap,
            self._purpose,
            self._set_path,
            self.chargers,
            self.parking,
            park_idle_s,
            battery,
        )
        # grants of a later policy (a restarted coordinator) must outrank older ones at the
        # robots: seq counts up from the wall time this policy was made, in microseconds
        self._seq_base = time.time_ns() // 1000

    # -- TrafficPolicy -----------------------------------------------------------------

    def on_assign(
        self, robot: str, route: RouteLike, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]:
        """``robot`` drives ``route`` for ``task_id`` from the next cycle on: a loop through its
        waypoint nodes (a patrol), or, if ``route.loop`` is false, once through them, stopping
        at each (a task's stops); ``poses`` are returned unchanged."""
        nodes = [str(n) for n in route.nodes]
        if nodes:
            self._pending[robot] = nodes
            self._task[robot] = task_id
            if getattr(route, "loop", True):
                self._once.discard(robot)
            else:
                self._once.add(robot)
            self._apply_pending(robot)
        return poses

    def on_release(self, robot: str) -> None:
        """``robot`` lost its patrol: it stops at the end of its current grant."""
        self._pending.pop(robot, None)
        self._task[robot] = None
        if self._purpose.get(robot) in (Purpose.PATROL, Purpose.TASK):
            self._purpose.pop(robot, None)
        if self.manager.knows(robot) and self.manager.is_alive(robot):
            self.manager.clear_path(robot, self._now)

    def waiting(self, robot: str) -> bool:
        """True while ``robot`` stands still because the manager has not granted it more
        path, for a live robot ahead (so the coordinator must not call it stuck). A robot
        held up by a dead robot is not "waiting": the coordinator's stuck rule then gives its
        route to a robot that can reach it."""
        m = self.manager
        if not m.knows(robot):
            return robot in self._pending or robot in self._task and self._task[robot] is not None
        if not m.is_waiting(robot):
            return False
        return not any(m.knows(b) and not m.is_alive(b) for b in m.blockers(robot))

    def cycle(self, now: float, robots: Mapping[str, RobotViewLike]) -> tuple[()]:
        """One policy cycle at ``now`` over every robot's view (see the class docstring);
        grants go out through ``deliver``, so no extra orders are returned."""
        self._now = now
        m = self.manager
        requests: list[tuple[float, str]] = []
        for name, v in robots.items():
            if not self._observe(name, v, now):
                continue
            if name in self._pending:
                self._apply_pending(name)
            self.errands.step(name, v, now, requests)
        self.errands.serve_chargers(requests)
        if m.params.contraflow_m > 0.0:
            for name, purpose in list(self._purpose.items()):
                if purpose in ERRANDS and m.knows(name):
                    m.shorten_errand(name, now)
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
        purpose = self._purpose.get(robot)
        patrol = purpose is Purpose.PATROL
        task = self._task.get(robot) if purpose in (Purpose.PATROL, Purpose.TASK) else None
        laps = self.manager.laps(robot) if patrol else 0
        return msgspec.structs.replace(g, task_id=task, purpose=purpose or "", laps=laps, seq=seq)

    def purpose(self, robot: str) -> Purpose | None:
        """Why ``robot`` drives now (``None``: no errand)."""
        return self._purpose.get(robot)

    def mean_wait_s(self, now: float) -> float:
        """Mean over managed robots of their total wait for right of way (s)."""
        return self.manager.mean_wait_s(now)

    # -- internals ---------------------------------------------------------------------

    def _observe(self, name: str, v: RobotViewLike, now: float) -> bool:
        """Feed one view into the manager (register, liveness, pose); False if the robot
        is not (or no longer) driven this cycle."""
        m = self.manager
        obs = v.obs
        pose = obs.pose if obs is not None else None
        alive = bool(v.alive)
        if not m.knows(name):
            if pose is None or not alive:
                return False
            try:
                m.add_robot(name, pose, now)
            except TrafficError:
                return False  # its node is held: it stays put, unregistered, until it is free
        if not alive:
            if m.is_alive(name):
                # its agent is gone but the robot may still drive its last goal: it
                # keeps its whole grant
                m.declare_dead(name, now, "coordinator: dead", keep_grant=True)
                self._dead_since[name] = now
            since = self._dead_since.get(name)
            if since is not None and now - since >= self.dead_release_s:
                # it has had time to finish its last goal: keep only the node it stands on
                m.release_dead(name, now)
                del self._dead_since[name]
            self._coord_dead.add(name)
            self._purpose.pop(name, None)
            return False
        if name in self._coord_dead:
            self._coord_dead.discard(name)
            self._dead_since.pop(name, None)
            m.declare_alive(name, now)
        if pose is not None:
            m.update(name, pose, now)
        return True

    def _set_path(
        self,
        robot: str,
        nodes: list[str],
        purpose: Purpose,
        must: list[int] | None = None,
        loop: bool = False,
    ) -> None:
        m = self.manager
        if not m.is_alive(robot):
            m.declare_alive(robot, self._now)  # e.g. stalled earlier: a new errand revives it
        # errands (charger, parking) may turn back instead of finishing the patrol's grant
        errand = purpose in ERRANDS
        m.set_path(robot, nodes, self._now, must_visit=must, loop=loop, turn_back=errand)
        self._purpose[robot] = purpose

    def _apply_pending(self, robot: str) -> None:
        m = self.manager
        if m.knows(robot):
            m.set_priority(robot, 0.0)
            m.set_detour_limit(robot, None)
        nodes = self._pending.get(robot)
        if nodes is None or not m.knows(robot) or robot in self._coord_dead:
            return
        del self._pending[robot]
        self.errands.forget(robot)
        if robot in self._once:  # a task's stops, driven once; every stop must be visited
            path = m.route(nodes)  # legs with the flow, like errands
            stops = set(nodes)
            self._set_path(robot, path, Purpose.TASK, must=[i for i, n in enumerate(path) if n in stops])
            return
        loop = self.roadmap.expand_route(nodes, closed=True)
        wps = set(nodes)
        if len(loop) < 2:
            self._set_path(robot, loop, Purpose.PATROL)
        else:
            must = [i for i, n in enumerate(loop) if n in wps]
            self._set_path(robot, loop, Purpose.PATROL, must=must, loop=True)

    def _count_deadlocks(self, now: float) -> None:
        if now - self._last_dl < self.manager.params.detect_period_s:
            return
        self._last_dl = now
        current = set(self.manager.deadlocked(now, self.deadlock_s))
        for c in current - self._open_deadlocks:
            self.deadlocks += 1
            self.deadlock_events.append((now, tuple(sorted(c))))
            if len(self.deadlock_events) > MAX_DEADLOCK_EVENTS:
                del self.deadlock_events[: MAX_DEADLOCK_EVENTS // 2]
        self._open_deadlocks = current


def traffic_from_config(config: FleetConfig, deliver: Deliver | None = None) -> ReservationTraffic:
    """The :class:`ReservationTraffic` of a fleet config: its roadmap with the chargers,
    parking spots and robot start poses joined as docks (:func:`fleet.roadmap.docks.add_docks`),
    :class:`TrafficParams` from ``robot_model.radius`` and the ``traffic`` section, the
    direction of its patrol loops as the fleet's flow (:meth:`TrafficManager.set_flow`). Raises
    :class:`~fleet.errors.ConfigError` (field ``traffic``) if a dock cannot be joined."""
    ts = config.traffic
    params = TrafficParams(
        robot_radius=config.sim.model.radius,
        horizon_m=ts.horizon_m,
        stall_timeout_s=ts.stall_timeout_s,
        cell_m=ts.cell_m,
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
    if params.cell_m is not None:
        g = split_cells(g, params.cell_m, params.clearance)
    chargers = [node_of[f"charger:{c.name}"] for c in config.chargers]
    # idle robots park only on docks (a start pose on a roadmap node is no parking spot)
    parking = [
        node_of[label]
        for label, _ in docks
        if not label.startswith("charger:") and g.nodes[node_of[label]].get("dock")
    ]
    roadmap = Roadmap.from_graph(g)
    policy = ReservationTraffic(
        roadmap,
        params,
        deliver,
        chargers=chargers,
        parking=parking,
        deadlock_s=ts.deadlock_s,
        park_idle_s=ts.park_idle_s,
        dead_release_s=ts.dead_release_s,
        battery=config.sim.battery,
    )
    policy.manager.set_flow(_loop_moves(roadmap, config))
    return policy


def _loop_moves(roadmap: Roadmap, config: FleetConfig) -> list[tuple[str, str]]:
    """The directed edges of the config's patrol loops (routes through roadmap nodes)."""
    moves: list[tuple[str, str]] = []
    for route in config.routes:
        nodes = [n for n in route.node_names if n is not None]
        if len(nodes) < 2 or len(nodes) < len(route.node_names):
            continue
        try:
            loop = roadmap.expand_route(nodes, closed=True)
        except (KeyError, ValueError):
            continue
        moves += list(zip(loop, loop[1:] + loop[:1], strict=True))
    return moves
