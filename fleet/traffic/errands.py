"""Charging and parking trips of the traffic policy (``docs/traffic.md``, "Who decides what").

* A robot whose status mode is ``charging`` is given a charger dock that nobody holds or
  heads for, or one an idle robot stands on (that robot is sent to park at once): which
  robot gets which is :func:`fleet.traffic.charger_queue.assign_chargers` (robots that
  cannot afford to wait first, then the nearest robot-charger pairs), among the chargers at
  most :data:`CHARGE_REACH_M` farther than its nearest. The dock is reserved for it from
  then on. A robot that got none and can afford a wait is sent straight to the busy charger
  that frees first if it frees before the robot gets there (next in line,
  :meth:`Errands._queue_on`); otherwise it waits at a free parking dock nearest the chargers
  (:attr:`Purpose.CHARGE_WAIT`) and is sent on when a charger frees. On its way it has base
  priority ``CHARGE_PRIORITY * (2 - battery)`` and takes no detour around a dead robot
  longer than :data:`CHARGE_DETOUR_M` beyond its way.
* A robot idle on a charger (a charge done, or a top-up) that another robot was given or
  is next in line for leaves it for the nearest free parking dock at once, instead of
  ``park_idle_s`` later.
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
from typing import TYPE_CHECKING, cast

import networkx as nx

from fleet.robots import BatteryModel
from fleet.traffic.charger_queue import ChargeNeed, assign_chargers, spare, urgent_below
from fleet.traffic.manager import TrafficManager
from fleet.traffic.purpose import CHARGE_PRIORITY, Purpose
from fleet.traffic.views import RobotViewLike
from fleet.types import Mode

if TYPE_CHECKING:
    from fleet.roadmap.graph import Roadmap

#: An idle robot below this battery fraction waits on a free charger instead of a parking spot
#: (it charges while it waits for work), so idle robots do not all run low together.
TOP_UP_BELOW = 0.6
#: ... but only while more than this share of the chargers is free (kept for robots in need).
SPARE_CHARGERS = 0.1
#: An idle robot on a charger above this battery fraction leaves it to an idle robot that
#: wants to top up and found no free charger.
VACATE_ABOVE = 0.9

#: A robot that needs a charger takes a free one at most this much (m, driving with the flow)
#: farther than its nearest charger; otherwise it waits for one near it: a charger frees
#: within about a minute (a charge from 30 % takes 33 s at 0.02 /s), a trip across a wide
#: floor costs minutes in traffic and energy the robot may not have.
CHARGE_REACH_M = 30.0

#: A robot on a dock errand (to a charger, or to a parking dock to wait or park) that has
#: waited this long (s) on the same robots takes the nearest free dock of the same kind it can
#: reach without passing them (two robots head-on in a corridor, each heading for a charger
#: behind the other, swap chargers instead of waiting for a step-aside that has no room).
RETARGET_AFTER_S = 10.0
#: ... within this much driving (m) of where it stands.
RETARGET_REACH_M = 60.0

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
    way to give a robot a path; ``chargers`` / ``parking``: dock node names; ``battery``: the
    fleet's battery model (the energy of a trip to a charger, the reserve, ``resume``).
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
        self.roadmap = roadmap
        self.purposes = purposes
        self.drive = drive
        self.chargers = list(chargers)
        self.parking = list(parking)
        self.park_idle_s = float(park_idle_s)
        self.battery = battery or BatteryModel()
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
        # idle robots standing on a charger this cycle (charger -> robot): a robot that needs
        # a charger may take one, and the idle robot leaves it
        self._idle_on: dict[str, str] = {}
        # the battery of every robot as last seen
        self._battery_of: dict[str, float] = {}

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
        if obs is not None:
            self._battery_of[name] = float(obs.battery)
        purpose = self.purposes.get(name)
        target = self._target.get(name)
        if target is not None and not self._may_enter(name, target) and not self._queued(name, target):
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
        path = self.manager.path(name)
        here = path[0] if path else None
        if purpose is Purpose.PARK and here != self._target.get(name):
            return  # on its way to park
        if here in self._charger_set:
            assert obs is not None
            self._idle_on[here] = name
            if self._queued_for(here, name):
                # another robot comes for this charger: leave it at once
                self._go(name, self._free_dock(name, self.parking), Purpose.PARK)
                return
        if now - since < self.park_idle_s:
            return
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

    def _top_up(self, name: str, battery: float) -> bool:
        """Send the idle ``name`` to wait on a free charger (charging there) when its battery
        is below :data:`TOP_UP_BELOW`, nobody waits for a charger and more than
        :data:`SPARE_CHARGERS` of the chargers are free; whether it was sent."""
        if battery >= TOP_UP_BELOW or self._charge_wait or not self.chargers:
            return False
        m = self.manager
        taken = set(self._target.values())
        free = sum(1 for c in self.chargers if m.holder(c) is None and c not in taken)
        if free < 1 or free <= SPARE_CHARGERS * len(self.chargers):
            self._wanting += 1
            return False
        node = self._free_dock(name, self.chargers)
        if node is None:
            return False
        self._go(name, node, Purpose.PARK)
        return True

    def serve_chargers(self, requests: list[tuple[float, str]]) -> None:
        """Hand chargers to the robots that need one (:func:`assign_chargers` over the
        chargers each may take, within :data:`CHARGE_REACH_M` of its nearest); the others
        wait on a free parking dock near the chargers (once; they stay there until a charger
        frees). Called once per cycle, after :meth:`step` of every robot."""
        self._wanted, self._wanting = self._wanting, 0
        idle_on, self._idle_on = self._idle_on, {}
        if not requests:
            return
        m = self.manager
        needs: list[ChargeNeed] = []
        reach: dict[str, dict[str, float]] = {}
        for battery, name in sorted(requests):
            # a robot short of energy goes first at intersections and is never the one to yield,
            # and does not drive far round a dead robot
            m.set_priority(name, CHARGE_PRIORITY * (2.0 - battery))
            m.set_detour_limit(name, CHARGE_DETOUR_M)
            path = m.path(name)
            if not path or not self.chargers:
                continue
            near = m.costs_near(path[0], self.chargers, CHARGE_REACH_M)
            may = {c: d for c, d in near.items() if self._takes(name, c, idle_on)}
            needs.append(ChargeNeed(name, battery, may))
            reach[name] = near
        got = assign_chargers(needs, self.battery)
        near_of = reach
        battery_of = {n.robot: n.battery for n in needs}
        for _, name in sorted(requests):
            node = got.get(name)
            if node is not None and self._vacate(node, idle_on):
                self._go(name, node, Purpose.CHARGE)
        for _, name in sorted(requests):
            if name in got or self.purposes.get(name) is Purpose.CHARGE_WAIT:
                continue
            # wait off the aisles for a charger near it; unless the waiting place is farther
            # than a free charger (then it drives to that charger instead)
            dock = self._free_dock(name, self.parking, self._to_charger())
            far = self._free_dock(name, self.chargers)
            if far is not None and (dock is None or self._cost(name, far, dock)):
                self._go(name, far, Purpose.CHARGE)
            elif not self._queue_on(name, battery_of.get(name, 0.0), near_of.get(name, {})):
                self._go(name, dock, Purpose.CHARGE_WAIT)

    def _queue_on(self, robot: str, battery: float, costs: Mapping[str, float]) -> bool:
        """Send ``robot`` straight to the charger of ``costs`` (roadmap cost in m) that frees
        first, if it frees before ``robot`` gets there (driving at ``cruise_mps``; the robot
        charging on it needs ``(resume - battery) / charge_per_s``), nobody else is queued
        for it and ``robot`` can afford a wait (:func:`urgent_below`); the charger is then
        reserved for it as the next in line. Whether it was sent."""
        m, model = self.manager, self.battery
        if spare(model, battery, min(costs.values(), default=math.inf)) < urgent_below(model):
            return False
        best: tuple[float, str] | None = None
        for c, cost in costs.items():
            h = m.holder(c)
            if h is None or self._target.get(h) != c or self.purposes.get(h) is not Purpose.CHARGE:
                continue
            if any(n == c and r != h for r, n in self._target.items()):
                continue  # somebody is already next
            frees = max(0.0, model.resume - self._battery_of.get(h, 0.0)) / model.charge_per_s
            if frees <= cost / model.cruise_mps and (best is None or (frees, c) < best):
                best = (frees, c)
        if best is None:
            return False
        self._go(robot, best[1], Purpose.CHARGE)
        return True

    def _queued(self, robot: str, dock: str) -> bool:
        """``robot`` is next in line for ``dock``: the robot on it charges there (its target)."""
        holder = self.manager.holder(dock)
        return holder is not None and holder != robot and self._target.get(holder) == dock

    def _queued_for(self, dock: str, robot: str) -> bool:
        """Another robot than ``robot`` heads for ``dock``."""
        return any(n == dock and r != robot for r, n in self._target.items())

    def _takes(self, robot: str, charger: str, idle_on: Mapping[str, str]) -> bool:
        """``robot`` may be sent to ``charger`` now: nobody else heads for it, and nobody
        stands on it but a robot that leaves it or an idle robot (``idle_on``)."""
        holder = self.manager.holder(charger)
        for r, n in self._target.items():
            if n == charger and r not in (robot, holder):
                return False
        return self._may_enter(robot, charger) or (holder is not None and idle_on.get(charger) == holder)

    def _vacate(self, charger: str, idle_on: Mapping[str, str]) -> bool:
        """Send the idle robot on ``charger`` (if any) to park, so the robot given it can
        charge; False if it has nowhere to go (then it stays and the charger is not given)."""
        holder = self.manager.holder(charger)
        if holder is None or idle_on.get(charger) != holder:
            return True
        dock = self._free_dock(holder, self.parking)
        if dock is None:
            return False
        self._go(holder, dock, Purpose.PARK)
        return True

    def _may_enter(self, robot: str, dock: str) -> bool:
        """Nobody but ``robot`` holds ``dock``, or the robot on it is leaving: it has work
        (a patrol or a task), or it was sent to park on another dock. A robot sent to such a
        dock waits before the junction at its spur until it is free
        (:func:`fleet.traffic.grants.block`)."""
        holder = self.manager.holder(dock)
        if holder in (None, robot):
            return True
        assert holder is not None
        purpose = self.purposes.get(holder)
        if purpose in (Purpose.PATROL, Purpose.TASK):
            return True
        return purpose is Purpose.PARK and self._target.get(holder) not in (None, dock)

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
        :attr:`Purpose.CHARGE`, else parking) that it reaches within :data:`RETARGET_REACH_M`
        without entering a node its blockers hold; its current target counts too."""
        m = self.manager
        path = m.path(name)
        if not path:
            return
        here = path[0]
        avoid = {x for b in m.blockers(name) for x in m.held(b) if isinstance(x, str)}
        avoid.discard(here)

        def weight(u: str, v: str, d: dict[str, float]) -> float | None:
            return None if v in avoid else float(d.get("length", 1.0))

        found = nx.single_source_dijkstra(self.roadmap.graph, here, cutoff=RETARGET_REACH_M, weight=weight)
        dist, paths = cast("tuple[dict[str, float], dict[str, list[str]]]", found)
        docks = self.chargers if purpose is Purpose.CHARGE else self.parking
        taken = {n for r, n in self._target.items() if r != name}
        free = [d for d in docks if d in dist and d not in taken and m.holder(d) in (None, name)]
        if not free:
            return
        best = min(free, key=lambda d: (dist[d], d))
        self._target[name] = best
        self.drive(name, [str(n) for n in paths[best]], purpose)

    def _cost(self, robot: str, near: str, far: str) -> bool:
        """``near`` costs ``robot`` less to reach than ``far`` (roadmap cost with the flow from
        where it stands; a search that stops once it has found both)."""
        path = self.manager.path(robot)
        if not path:
            return False
        costs = self.manager.costs_near(path[0], (near, far))
        return costs.get(near, math.inf) < costs.get(far, math.inf)

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

    def _free_dock(
        self,
        robot: str,
        docks: Sequence[str],
        first: Mapping[str, float] | None = None,
    ) -> str | None:
        """The dock nearest ``robot`` (roadmap distance, driving with the fleet's flow:
        :meth:`TrafficManager.nearest`; with ``first``, the dock of least ``first[dock]``,
        then nearest) that nobody else heads for and nobody holds but a robot leaving it
        (:meth:`_may_enter`); ``None`` when there is none."""
        m = self.manager
        taken = {n for r, n in self._target.items() if r != robot}
        free = [d for d in docks if d not in taken and self._may_enter(robot, d)]
        if not free:
            return None
        path = m.path(robot)
        here = path[0] if path else self.roadmap.nearest_node(*m.node_pos(free[0]))
        if first is not None:  # the least ``first`` (to 0.1 m) first, then the nearest of those
            least = min(round(first.get(d, math.inf), 1) for d in free)
            free = [d for d in free if round(first.get(d, math.inf), 1) == least]
        return m.nearest(here, free)  # the way the manager will drive it: with the flow
