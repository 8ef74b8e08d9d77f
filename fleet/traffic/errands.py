"""Charging and parking trips of the traffic policy (``docs/traffic.md``, "Who decides what").

* A robot whose status mode is ``charging`` is sent to the nearest charger dock that nobody
  holds or heads for, lowest battery first; if every charger is taken it waits at a free
  parking dock nearest the chargers (:attr:`Purpose.CHARGE_WAIT`) and is sent on when a
  charger frees. On its way it has base priority ``CHARGE_PRIORITY * (2 - battery)`` and
  takes no detour around a dead robot longer than :data:`CHARGE_DETOUR_M` beyond its way.
* A robot idle (no route, mode ``idle``) for ``park_idle_s`` that does not stand on a
  parking or charger dock is sent to the nearest free parking dock, so idle robots do not
  stand in aisles; one below :data:`TOP_UP_BELOW` battery goes to a free charger instead
  (while more than :data:`SPARE_CHARGERS` of them are free), parked robots too. A robot on
  a charger dock is moved to parking when another robot waits for a charger, or when it
  has charged above :data:`VACATE_ABOVE` and an idle robot below :data:`TOP_UP_BELOW` found
  no free charger (so chargers do not fill up with full robots while others drain).
* A robot whose target dock another robot stepped onto picks another dock."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from operator import countOf
from typing import TYPE_CHECKING

import networkx as nx

from fleet.traffic.manager import TrafficManager
from fleet.traffic.purpose import CHARGE_PRIORITY, CHARGE_REACH_M, Purpose
from fleet.traffic.views import RobotViewLike
from fleet.types import Mode

if TYPE_CHECKING:
    from fleet.roadmap.graph import Roadmap
    from fleet.robots import BatteryModel

#: An idle robot below this battery fraction waits on a free charger instead of a parking spot
#: (it charges while it waits for work), so idle robots do not all run low together.
TOP_UP_BELOW = 0.6
#: ... but only while more than this share of the chargers is free (kept for robots in need).
SPARE_CHARGERS = 0.1
#: An idle robot on a charger above this battery fraction leaves it to an idle robot that
#: wants to top up and found no free charger.
VACATE_ABOVE = 0.9

#: A robot on a dock errand (to a charger, or to a parking dock to wait or park) that has
#: waited this long (s) on the same robots takes the nearest free dock of the same kind it can
#: reach without passing them (two robots head-on in a corridor, each heading for a charger
#: behind the other, swap chargers instead of waiting for a step-aside that has no room).
#: The dock must be within ``TrafficParams.retarget_reach_m`` of driving (m).
RETARGET_AFTER_S = 10.0

#: A robot that needs a charger takes a detour around a dead robot (an agent being restarted,
#: usually back within seconds) only if it is at most this much (m) longer than its way; else
#: it waits (:meth:`TrafficManager.set_detour_limit`). Unbounded, such detours through the
#: aisles drained robots on their way to a charger flat under chaos (docs/faults.md).
CHARGE_DETOUR_M = 10.0

#: Sends a robot along a node path for a purpose: ``drive(robot, nodes, purpose)``.
Drive = Callable[[str, list[str], Purpose], None]


class Errands:
    """The charger queue and the parking docks (see the module docstring).

    ``manager``: the policy's traffic manager; ``roadmap``: its roadmap (with docks, edge
    attribute ``length`` in m); ``purposes``: the policy's purpose per robot (shared:
    errands set and drop ``CHARGE``, ``CHARGE_WAIT`` and ``PARK``); ``drive``: the policy's
    way to give a robot a path; ``chargers`` / ``parking``: dock node names; ``battery``:
    the fleet's battery model (for ``TrafficParams.charge_margin_priority``; without it
    robots are ranked by battery alone).
    """

    def __init__(
        self,
        manager: TrafficManager,
        roadmap: Roadmap,
        purposes: dict[str, Purpose],
        drive: Drive,
        chargers: Sequence[str],
        parking: Sequence[str],
        park_idle_s: float,
        battery: BatteryModel | None = None,
    ) -> None:
        self.manager = manager
        self.battery = battery
        self.roadmap = roadmap
        self.purposes = purposes
        self.drive = drive
        self.chargers = list(chargers)
        self.parking = list(parking)
        self.park_idle_s = float(park_idle_s)
        self._parking_set = set(self.parking)
        self._charger_set = set(self.chargers)
        self._target: dict[str, str] = {}
        self._idle_since: dict[str, float] = {}
        self._charge_wait: set[str] = set()
        self._charger_dist: dict[str, float] | None = None
        # idle robots that wanted to top up and found no free charger: this cycle, last cycle
        self._wanting = 0
        self._wanted = 0
        # robots on dock errands waiting on the same robots: name -> (blockers, since)
        self._stuck: dict[str, tuple[frozenset[str], float]] = {}
        self._waiting: tuple[float, set[str]] = (-math.inf, set())

    def forget(self, robot: str) -> None:
        """``robot`` got a patrol: drop its dock target and its place in the charger queue."""
        self._target.pop(robot, None)
        self._charge_wait.discard(robot)
        self._stuck.pop(robot, None)

    def step(self, name: str, view: RobotViewLike, now: float, requests: list[tuple[float, str]]) -> None:
        """Charging and parking trips of the live robot ``name`` at ``now``. A robot that needs
        a charger is added to ``requests`` as ``(battery, robot)``: :meth:`serve_chargers`."""
        obs = view.obs
        mode = obs.mode if obs is not None else None
        purpose = self.purposes.get(name)
        target = self._target.get(name)
        if target is not None and self.manager.holder(target) not in (None, name):
            # another robot stepped onto the dock this robot heads for (e.g. to let a third
            # pass): choose another dock rather than wait for it, head-on on a dead-end spur
            self._target.pop(name, None)
            if purpose in (Purpose.CHARGE, Purpose.CHARGE_WAIT):
                self.purposes.pop(name, None)
                self._charge_wait.discard(name)
                purpose = None
            elif purpose is Purpose.PARK:
                self._go(name, self._free_dock(name, self.parking), Purpose.PARK)
                return
        if target is not None and purpose is Purpose.CHARGE and self._charge_here(name, target):
            return
        if target is not None and purpose in (Purpose.CHARGE, Purpose.CHARGE_WAIT, Purpose.PARK):
            path = self.manager.path(name)
            if path and path[-1] != target:
                # nudged aside to a node of its own (a parked robot makes room): its errand
                # still stands, or it would stop there with charging to do and no way on
                self.drive(name, [target], purpose)
            elif self._blocked_long(name, now):
                self._retarget(name, purpose)
        if mode == Mode.CHARGING:
            self._idle_since.pop(name, None)
            if purpose is Purpose.CHARGE and self._by_margin():
                assert obs is not None
                margin = float(obs.battery) - self._need(self._way_left(name))
                self.manager.set_priority(name, CHARGE_PRIORITY * (2.0 - margin))
            if purpose is not Purpose.CHARGE:
                assert obs is not None
                requests.append((float(obs.battery), name))
            return
        if mode != Mode.IDLE or view.assignment is not None:
            self._idle_since.pop(name, None)
            return
        if purpose in (Purpose.CHARGE, Purpose.CHARGE_WAIT):
            self.manager.set_priority(name, 0.0)
            self.manager.set_detour_limit(name, None)
            self.purposes.pop(name, None)  # charged: now simply idle where it stands
            self._target.pop(name, None)
            self._charge_wait.discard(name)
            purpose = None
        since = self._idle_since.setdefault(name, now)
        if now - since < self.park_idle_s:
            return
        path = self.manager.path(name)
        here = path[0] if path else None
        if purpose is Purpose.PARK and here != self._target.get(name):
            return  # on its way to park
        if here in self._charger_set:
            assert obs is not None
            full = float(obs.battery) >= VACATE_ABOVE
            if not self._charge_wait and not (self._wanted and full):
                return  # idle on a charger: it charges there until a robot needs it
        else:
            assert obs is not None
            if self._top_up(name, float(obs.battery)) or here in self._parking_set:
                return
        self._go(name, self._free_dock(name, self.parking), Purpose.PARK)

    def _charge_here(self, name: str, target: str) -> bool:
        """With ``TrafficParams.charge_where_stepped``: ``name``, on its way to the charger
        ``target``, stands on another charger dock (stepped aside or nudged there) that
        nobody else holds or heads for: that dock becomes its charger (it stops there) and
        ``target`` is freed for others. Whether it did."""
        m = self.manager
        if not m.params.charge_where_stepped:
            return False
        path = m.path(name)
        here = path[0] if path else None
        if here is None or here == target or here not in self._charger_set:
            return False
        if m.holder(here) not in (None, name) or any(n == here for r, n in self._target.items() if r != name):
            return False
        self._go(name, here, Purpose.CHARGE)
        return True

    def _top_up(self, name: str, battery: float) -> bool:
        """Send the idle ``name`` to wait on a free charger (charging there) when its battery
        is below :data:`TOP_UP_BELOW`, nobody waits for a charger and more than
        :data:`SPARE_CHARGERS` of the chargers are free; whether it was sent."""
        if battery >= TOP_UP_BELOW or self._charge_wait or not self.chargers:
            return False
        free = len(self.manager.free_docks(None, self.chargers, set(self._target.values())))
        if free < 1 or free <= SPARE_CHARGERS * len(self.chargers):
            self._wanting += 1
            return False
        node = self._free_dock(name, self.chargers)
        if node is None:
            return False
        self._go(name, node, Purpose.PARK)
        return True

    def serve_chargers(self, requests: list[tuple[float, str]]) -> None:
        """Free chargers go to the robots with the lowest battery first (with
        ``TrafficParams.charge_margin_priority``: the least battery left once at the nearest
        charger); the others wait on a
        free parking dock near the chargers (once; they stay there until a charger frees).
        Called once per cycle, after :meth:`step` of every robot."""
        self._wanted, self._wanting = self._wanting, 0
        if not requests:
            return
        if self._by_margin():  # least energy left once at its nearest charger first
            to = self._to_charger()
            ranked = sorted((b - self._need(to.get(self._here(n), 0.0)), n) for b, n in requests)
        else:
            ranked = sorted(requests)
        for battery, name in ranked:
            # a robot short of energy goes first at intersections and is never the one to yield,
            # and does not drive far round a dead robot
            self.manager.set_priority(name, CHARGE_PRIORITY * (2.0 - battery))
            self.manager.set_detour_limit(name, CHARGE_DETOUR_M)
            node = self._free_dock(name, self.chargers, reach=CHARGE_REACH_M)
            if node is not None:
                self._go(name, node, Purpose.CHARGE)
            elif self.purposes.get(name) is not Purpose.CHARGE_WAIT:
                # wait off the aisles for a charger near it; unless the waiting place is
                # farther than a free charger (then it drives to that charger instead)
                dock = self._free_dock(name, self.parking, self._to_charger())
                far = self._free_dock(name, self.chargers)
                if far is not None and (dock is None or self._cost(name, far) < self._cost(name, dock)):
                    self._go(name, far, Purpose.CHARGE)
                else:
                    self._go(name, dock, Purpose.CHARGE_WAIT)

    def _blocked_long(self, name: str, now: float) -> bool:
        """``name`` has waited :data:`RETARGET_AFTER_S` on the same robots (then the clock
        starts again)."""
        if self._waiting[0] != now:
            self._waiting = (now, self.manager.waiting())
        if name not in self._waiting[1]:
            self._stuck.pop(name, None)
            return False
        blockers = frozenset(self.manager.blockers(name))
        prev = self._stuck.get(name)
        if prev is None or prev[0] != blockers:
            self._stuck[name] = (blockers, now)
            return False
        if now - prev[1] < RETARGET_AFTER_S:
            return False
        self._stuck[name] = (blockers, now)
        return bool(blockers)

    def _retarget(self, name: str, purpose: Purpose) -> None:
        """Send ``name`` to the nearest free dock of its errand's kind (chargers for
        :attr:`Purpose.CHARGE`, else parking) that it reaches within ``TrafficParams.retarget_reach_m``
        without entering a node its blockers hold; its current target counts too. With
        ``TrafficParams.retarget_shorter`` only a way shorter than the rest of its current
        path is taken (else it waits where it is)."""
        m = self.manager
        path = m.path(name)
        if not path:
            return
        here = path[0]
        avoid = {x for b in m.blockers(name) for x in m.held(b) if isinstance(x, str)}
        avoid.discard(here)

        def weight(u: str, v: str, d: dict[str, float]) -> float | None:
            return None if v in avoid else float(d.get("length", 1.0))

        reach = m.params.retarget_reach_m
        # the search of nx.single_source_dijkstra without its path to every node reached (most
        # of its cost on a large floor): the one path taken is rebuilt from the predecessors
        pred, dist = nx.dijkstra_predecessor_and_distance(
            self.roadmap.graph, here, cutoff=reach, weight=weight
        )
        docks = self.chargers if purpose is Purpose.CHARGE else self.parking
        taken = {n for r, n in self._target.items() if r != name}
        free = [d for d in docks if d in dist and d not in taken and m.holder(d) in (None, name)]
        if not free:
            return
        best = min(free, key=lambda d: (dist[d], d))
        if m.params.retarget_shorter and dist[best] >= self._way_left(name) - 1e-9:
            return  # no way round the blockers shorter than the one it waits on: it waits
        self._target[name] = best
        self.drive(name, [str(n) for n in first_path(pred, here, best)], purpose)

    def _by_margin(self) -> bool:
        return self.battery is not None and self.manager.params.charge_margin_priority

    def _need(self, meters: float) -> float:
        """Battery fraction a robot uses driving ``meters`` of roadmap (the battery model's
        drive part of :meth:`BatteryModel.charge_threshold`, no waiting, no margin)."""
        b = self.battery
        if b is None:
            return 0.0
        d = max(0.0, meters) * b.detour
        return b.drain_per_m * d + b.drain_per_s * d / b.cruise_mps

    def _here(self, name: str) -> str:
        path = self.manager.path(name)
        return path[0] if path else ""

    def _way_left(self, name: str) -> float:
        """Length (m) of ``name``'s path from the node it last reached to its end."""
        path = self.manager.path(name)
        g = self.roadmap.graph
        return sum(float(g.edges[u, v].get("length", 1.0)) for u, v in zip(path, path[1:], strict=False))

    def _cost(self, robot: str, node: str) -> float:
        """Roadmap cost (m, with the flow) from where ``robot`` stands to ``node`` (a search
        that stops there)."""
        path = self.manager.path(robot)
        if not path:
            return math.inf
        return self.manager.costs_near(path[0], (node,)).get(node, math.inf)

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

    def _go(self, name: str, node: str | None, purpose: Purpose) -> None:
        if node is None:
            return
        self._target[name] = node
        if purpose is Purpose.CHARGE_WAIT:
            self._charge_wait.add(name)
        else:
            self._charge_wait.discard(name)
        self.drive(name, [node], purpose)

    def _taken_by_others(self, robot: str) -> set[str]:
        """The docks robots other than ``robot`` head for: ``{n for r, n in _target.items() if
        r != robot}``, built by set operations (every queued robot asks every cycle)."""
        targets = self._target
        taken = set(targets.values())
        own = targets.get(robot)
        if own is not None and countOf(targets.values(), own) == 1:
            taken.discard(own)
        return taken

    def _free_dock(
        self,
        robot: str,
        docks: Sequence[str],
        first: Mapping[str, float] | None = None,
        reach: float = math.inf,
    ) -> str | None:
        """The dock nearest ``robot`` (roadmap distance, driving with the fleet's flow:
        :meth:`TrafficManager.costs_from`; with ``first``, the dock of least
        ``first[dock]``, then nearest) that nobody else holds or heads for; ``None`` when
        there is none, or when the nearest free one is more than ``reach`` m farther than
        the nearest of all ``docks`` (taken or not). With a finite ``reach`` the search
        stops ``reach`` past the nearest dock (:meth:`TrafficManager.costs_near`) instead
        of costing the whole roadmap: the same answer."""
        m = self.manager
        free = m.free_docks(robot, docks, self._taken_by_others(robot))
        if not free:
            return None
        path = m.path(robot)
        here = path[0] if path else self.roadmap.nearest_node(*m.node_pos(free[0]))
        if first is not None:  # the least ``first`` (to 0.1 m) first, then the nearest of those
            least = min(round(first.get(d, math.inf), 1) for d in free)
            free = [d for d in free if round(first.get(d, math.inf), 1) == least]
        if first is not None or reach == math.inf:
            return m.nearest(here, free)  # the way the manager will drive it: with the flow
        dist = m.costs_near(here, docks, reach)
        if not dist:  # no dock reachable at all: the least name, as a whole search gives
            return min(free)
        near = [d for d in free if d in dist]
        if not near:
            return None  # a charger near it frees soon (charging takes about a minute)
        return min(near, key=lambda d: (dist[d], d))


def first_path(pred: Mapping[str, list[str]], source: str, node: str) -> list[str]:
    """The path from ``source`` to ``node`` of a Dijkstra search's predecessor lists (``pred``:
    networkx's ``dijkstra_predecessor_and_distance`` from ``source``), back along each node's
    first predecessor: the path ``nx.single_source_dijkstra`` gives for ``node`` (both keep,
    per node, the predecessor that first reached it at its final distance)."""
    path = [node]
    while path[-1] != source:
        path.append(pred[path[-1]][0])
    path.reverse()
    return path
