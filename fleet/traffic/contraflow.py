"""Errands against the flow, reserved end to end (``TrafficParams.contraflow_m``).

A robot on an errand (to a charger or a parking dock) may take a way that drives against the
fleet's patrol flow (:func:`fleet.traffic.paths.errand_way`). With ``contraflow_m`` set, such
a way is taken only when its *stretch* (from where it starts to the node after its last step
against the flow) is at most ``contraflow_m`` long and nobody else holds or claims any node
or edge of it; the robot then reserves the whole stretch at once, so no robot can drive into
it head-on until the robot has passed (what it passes is released behind it as usual). The
manager also looks again, every ``detect_period_s``, for such a way for robots already on an
errand (:meth:`fleet.traffic.manager.TrafficManager.shorten_errand`): a stretch held a moment
ago by a robot that was leaving the charger is often free a second later.
"""

from __future__ import annotations

from collections.abc import Sequence

from fleet.traffic.reservations import Resource, edge_key
from fleet.traffic.roads import RoadIndex
from fleet.traffic.state import TrackedRobot, TrafficState

#: A robot already on an errand takes a new way only if it is at least this much (m) shorter
#: than the rest of its path (no switching back and forth for a cell's length).
CONTRAFLOW_GAIN_M = 2.0


def stretch_end(roads: RoadIndex, way: Sequence[str]) -> int:
    """Index in ``way`` of the stretch's last node: the node after the way's last step driven
    against the flow (the way's end if that step is its last); 0 if no step of ``way`` is
    driven against the flow."""
    against = roads.against
    last = 0
    for i in range(1, len(way)):
        if (way[i - 1], way[i]) in against:
            last = i
    return 0 if last == 0 else min(last + 1, len(way) - 1)


def stretch_resources(way: Sequence[str], end: int) -> list[Resource]:
    """The nodes and edges driven along ``way[0..end]`` (``way[0]`` itself excluded)."""
    out: list[Resource] = []
    for i in range(1, end + 1):
        a, b = way[i - 1], way[i]
        out.append(b)
        if a != b:
            out.append(edge_key(a, b))
    return out


def reservable(st: TrafficState, r: TrackedRobot, way: Sequence[str]) -> bool:
    """Whether ``r`` may take ``way`` under the contraflow rule: it drives nothing against the
    flow, or its stretch is at most ``contraflow_m`` long (m) and no other robot holds or
    (alive) claims any node or edge of it."""
    end = stretch_end(st.roads, way)
    if end == 0:
        return True
    if st.roads.cost(way[: end + 1], flow=False) > st.params.contraflow_m:
        return False
    holder, claims, robots = st.table.holder, st.claims, st.robots
    for x in stretch_resources(way, end):
        h = holder(x)
        if h is not None and h != r.name:
            return False
        c = claims.get(x)
        if c is not None and c != r.name and c in robots and robots[c].alive:
            return False
    return True


def reserve(st: TrafficState, r: TrackedRobot, way: Sequence[str]) -> None:
    """Grant ``r`` the stretch of ``way``, which was just installed from its grant's end on
    (``r.path[r.g] == way[0]``, checked :func:`reservable` this cycle): all of it at once."""
    end = stretch_end(st.roads, way)
    if end == 0:
        return
    base = r.g
    assert r.path[base] == way[0]
    bad = st.table.try_acquire(r.name, stretch_resources(way, end))
    if bad:  # not reservable after all: the grant grows block by block as usual
        return
    r.g = base + end
    r.prog_t = st.now
    st.changed.add(r.name)
