"""Navigation goals as SUMO routes: one route through the lane points of every pose, a stop at
the last one, and the progress along it.

A :class:`RoutePlan` holds the lane points of a navigation goal's poses and, once SUMO took it
(``applied``), the route, the route index of each target and the route length before each
edge. :class:`Router` computes and applies the route (:meth:`Router.apply`: the shortest
``findRoute`` path from the vehicle's edge through the edges of every pose in order, looping
round when a pose lies behind the vehicle on its own lane), follows the vehicle along it
(:meth:`Router.advance`: passed targets, the final stop, arrival) and measures what is left
(:meth:`Router.remaining`, junction crossings not counted). Units m; frame ``map``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fleet.robots import SimParams
from sim.goals import GoalRecord
from sim.sumo.lanes import LaneIndex, LanePoint
from sim.sumo.launch import ROBOT_TYPE, Libsumo
from sim.sumo.vehicles import FOREVER_S, Vehicle, Vehicles

#: A target counts as passed when the vehicle's front is this close (m) to its lane position.
POS_TOL_M = 0.3


@dataclass
class RoutePlan:
    """The route of one navigation goal (see the module docstring)."""

    targets: list[LanePoint] = field(default_factory=list)
    target_idx: list[int] = field(default_factory=list)  # route index of each target
    route: list[str] = field(default_factory=list)
    cum: list[float] = field(default_factory=list)  # route length before each route edge
    passed: int = 0  # number of targets passed
    applied: bool = False  # route/stop given to SUMO
    stop_after: int = -1  # route index after which the final stop is set (-1: it is set)


class Router:
    """Routes navigation goals for the vehicles of ``vehicles``."""

    def __init__(self, ls: Libsumo, lanes: LaneIndex, vehicles: Vehicles, params: SimParams) -> None:
        self.ls = ls
        self.lanes = lanes
        self.vehicles = vehicles
        self.params = params

    def route_between(self, a: str, b: str, loop: bool) -> list[str] | None:
        """Edges from ``a`` to ``b`` (both included); with ``loop`` and ``a == b``, a way round."""
        ls = self.ls
        if a == b and not loop:
            return [a]
        if a != b:
            r = ls.simulation.findRoute(a, b, ROBOT_TYPE)
            return list(r.edges) if r.edges else None
        best: list[str] | None = None
        best_len = math.inf
        for s in self.lanes.successors.get(a, []):
            r = ls.simulation.findRoute(s, b, ROBOT_TYPE) if s != b else None
            edges = list(r.edges) if r is not None and r.edges else ([s] if s == b else None)
            if not edges:
                continue
            length = r.length if r is not None else self.lanes.edge_length[s]
            if length < best_len:
                best, best_len = [a, *edges], length
        return best

    def _start(self, v: Vehicle) -> tuple[list[str], str, float] | None:
        """``(route prefix, edge, lane pos)`` the new route starts from: the vehicle's edge and
        the first position it can stop at, or the edge after the junction it is crossing;
        ``None`` while it is not on the network."""
        ls = self.ls
        if not v.present:
            return None
        road = ls.vehicle.getRoadID(v.vid)
        if not road:
            return None
        if road.startswith(":"):
            route = ls.vehicle.getRoute(v.vid)
            ri = ls.vehicle.getRouteIndex(v.vid)
            if ri + 1 >= len(route):
                return None
            return [route[ri]], route[ri + 1], -1.0
        pos = float(ls.vehicle.getLanePosition(v.vid))
        speed = float(ls.vehicle.getSpeed(v.vid))
        pos += speed * speed / (2.0 * self.params.model.max_linear_accel)  # cannot stop before this
        return [], road, pos

    def apply(self, v: Vehicle, plan: RoutePlan, record: GoalRecord) -> str | None:
        """Give SUMO the route and final stop of ``plan`` (retried each step while the vehicle
        is not yet on a normal edge or SUMO refuses; the refusal is shown in ``record``'s
        message meanwhile). Returns the reason when no route reaches a target (the goal fails
        with ``NO_VALID_PATH``)."""
        start = self._start(v)
        if start is None:
            return None
        prefix, edge, pos = start
        edges = [*prefix, edge]
        idx: list[int] = []
        cur_e, cur_p = edge, pos
        for t in plan.targets:
            front = self.vehicles.front_pos(t.edge, t.pos)
            if t.edge == cur_e and front >= cur_p - 1e-6:
                idx.append(len(edges) - 1)
            else:
                seg = self.route_between(cur_e, t.edge, loop=True)
                if seg is None:
                    return f"No SUMO route from edge {cur_e} to edge {t.edge}."
                edges += seg[1:]
                idx.append(len(edges) - 1)
            cur_e, cur_p = t.edge, front
        last = plan.targets[-1]
        # SUMO puts a stop on the first occurrence of its edge ahead in the route: when the
        # route passes the last pose's edge earlier (a loop), the stop is set once that is behind
        earlier = [j for j in range(idx[-1]) if edges[j] == last.edge]
        plan.stop_after = earlier[-1] if earlier else -1
        ls = self.ls
        try:
            self.vehicles.clear_stops(v)
            ls.vehicle.setRoute(v.vid, edges)
            if plan.stop_after < 0:
                self.set_final_stop(v, plan)
            ls.vehicle.setSpeed(v.vid, -1.0)
            self.vehicles.resting.pop(v.namespace, None)
        except Exception as exc:  # SUMO refused (e.g. cannot brake in time): retry next step
            record.error_msg = f"retrying route: {exc}"
            return None
        record.error_msg = ""
        self._applied(v, plan, edges, idx)
        return None

    def _applied(self, v: Vehicle, plan: RoutePlan, edges: list[str], idx: list[int]) -> None:
        plan.route = edges
        plan.target_idx = idx
        cum = [0.0]
        for e in edges:
            cum.append(cum[-1] + self.lanes.edge_length.get(e, 0.0))
        plan.cum = cum
        plan.passed = 0
        plan.applied = True
        self.vehicles.epoch += 1
        v.mode = "driving"

    def set_final_stop(self, v: Vehicle, plan: RoutePlan) -> None:
        """Stop the vehicle at the last target (front bumper at its lane position)."""
        last = plan.targets[-1]
        self.ls.vehicle.setStop(
            v.vid,
            last.edge,
            pos=self.vehicles.front_pos(last.edge, last.pos),
            laneIndex=last.lane,
            duration=FOREVER_S,
            flags=0,
        )
        plan.stop_after = -1

    def progress(self, v: Vehicle, plan: RoutePlan) -> tuple[int, float]:
        """``(route index, front lane pos)`` of the vehicle along the route (cached until the
        vehicles' epoch changes)."""
        if v.prog_epoch == self.vehicles.epoch:
            return v.prog
        ls = self.ls
        ri = int(ls.vehicle.getRouteIndex(v.vid))
        road = ls.vehicle.getRoadID(v.vid)
        if road.startswith(":"):
            prog = (ri, self.lanes.edge_length.get(plan.route[ri], 0.0) if 0 <= ri < len(plan.route) else 0.0)
        else:
            prog = (ri, float(ls.vehicle.getLanePosition(v.vid)))
        v.prog, v.prog_epoch = prog, self.vehicles.epoch
        return prog

    def advance(self, v: Vehicle, plan: RoutePlan) -> bool:
        """Count the targets the vehicle passed, set the final stop once a loop is behind it;
        return whether it has passed every target and stopped (the goal succeeded)."""
        ri, pos = self.progress(v, plan)
        if 0 <= plan.stop_after < ri:
            try:
                self.set_final_stop(v, plan)
            except Exception:  # retried next step
                pass
        while plan.passed < len(plan.targets):
            ti = plan.target_idx[plan.passed]
            t = plan.targets[plan.passed]
            if ri > ti or (ri == ti and pos >= self.vehicles.front_pos(t.edge, t.pos) - POS_TOL_M):
                plan.passed += 1
            else:
                break
        return plan.passed >= len(plan.targets) and bool(self.ls.vehicle.isStopped(v.vid))

    def remaining(self, v: Vehicle, plan: RoutePlan) -> float:
        """Route length (m) from the vehicle to the last target (junctions not counted)."""
        ri, pos = self.progress(v, plan)
        last = plan.targets[-1]
        end = plan.cum[plan.target_idx[-1]] + self.vehicles.front_pos(last.edge, last.pos)
        here = plan.cum[min(ri, len(plan.route) - 1)] + pos
        return max(0.0, end - here)
