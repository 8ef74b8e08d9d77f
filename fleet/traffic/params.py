"""Tunables of the traffic manager (meters, seconds)."""

from __future__ import annotations

from dataclasses import dataclass

#: How far ahead (path nodes) the manager looks for a robot coming the other way into a
#: corridor (see ``TrafficParams.hold_far_end``).
ONCOMING_NODES = 8


@dataclass(frozen=True)
class TrafficParams:
    """Tunables of :class:`TrafficManager` (meters, seconds).

    ``clearance_m``: a robot keeps a node until its center is farther than this from it; it
    must exceed two robot radii and be at most the shortest roadmap edge (default: twice
    ``robot_radius`` plus 0.3 m). ``arrive_m``: a robot has reached a path node when it is this
    close (larger than the navigation stack's via-point tolerance). ``horizon_m``: grants are
    extended while less than this much path is granted ahead (at least one block is always
    asked for). ``stall_timeout_s``: a robot with a grant ahead that moved less than
    ``progress_m`` for this long is treated as dead; ``stale_timeout_s`` (``None`` = off):
    likewise for a robot whose position was not updated for this long.
    ``deadlock_detect_s``: a wait-for cycle whose robots all waited this long is resolved;
    ``detect_period_s``: how often the wait-for graph is examined. ``starve_s``: a robot
    waiting longer claims the block it waits for. ``reroute_after_s``: a robot blocked this
    long by a dead or idle robot is rerouted (or the idle robot is nudged aside).
    ``reroute_factor`` / ``reroute_slack_m``: a yield-by-reroute is accepted only if the new
    way is at most ``factor * old + slack`` long. ``sidestep_depth``: how many edges away a
    robot may step aside. ``yield_timeout_s``: how long a robot that stepped aside lets the
    robots it yielded to go first. ``yield_bonus`` and ``aging_per_s`` weigh priority (see
    :meth:`TrafficManager.priority`). ``loop_min_nodes``: looped paths are kept at least this
    many nodes ahead of the grant. ``max_resolutions``: at most this many deadlocks and
    blocked robots are handled per detection pass (bounds the cost of one cycle).
    ``hold_far_end``: a robot entering a single-lane corridor also takes the junction at its
    far end, for the whole way through (the strict rule). Off (the default), it takes the far
    junction as a block of its own when it gets there, unless another robot's next
    :data:`ONCOMING_NODES` path nodes come from that junction into the corridor: then the
    strict rule applies, so robots meeting at a corridor's end stay rare while crossing
    traffic is not held up at every aisle end. ``follow``: a robot may enter a corridor
    behind robots that drive it the same way, node by node, instead of waiting for the
    whole corridor (:func:`fleet.traffic.grants.following`). ``flow_penalty``: the paths the
    manager plans itself (to a charger or parking dock, detours) cost an edge driven against
    the fleet's patrol loops ``1 + flow_penalty`` times its length
    (:meth:`fleet.traffic.roads.RoadIndex.set_flow`), so errands drive with the traffic.
    ``turn_back``: a robot sent on an errand (``set_path(..., turn_back=True)``: to a charger
    or a parking dock) may turn back and drive against the flow where nobody comes, giving
    up the part of its grant beyond the first node at least ``turn_back_m`` ahead of it,
    when that way is shorter (:func:`fleet.traffic.paths.errand_way`); ``turn_back_m`` must
    exceed the robot's stopping distance plus how far it drives before its follower learns
    of the shorter grant. ``dead_wait_s``: a robot with a detour limit
    (:meth:`TrafficManager.set_detour_limit`) blocked by a dead robot waits this long for it
    (a restarted agent is back within seconds) before it is rerouted around it.
    ``cell_m`` (``None`` = off): :func:`~fleet.traffic.policy.traffic_from_config` cuts every
    straight roadmap edge longer than this into pieces of at most ``cell_m`` (never shorter
    than ``clearance``; :func:`fleet.roadmap.cells.split_cells`), so a robot following
    another one the same way along an aisle closes up to about a cell behind it instead of
    a whole shelf bay.

    Charging errands (:class:`fleet.traffic.errands.Errands`; the defaults keep the
    behaviour measured on the shipped configs, ``docs/performance.md``, "Charging trips at
    100 robots", has what each switch does): ``charge_where_stepped``: a
    robot on its way to a charger that was stepped aside (or nudged) onto a free charger
    dock charges there instead of driving on to the charger it was sent to (a charging robot
    driving against the flow was stepped aside again and again and ran flat beside free
    chargers). ``retarget_reach_m``: a robot on a dock errand blocked on the same robots for
    :data:`~fleet.traffic.errands.RETARGET_AFTER_S` takes another dock only if it reaches it
    within this much driving (m); farther, it waits (at 100 robots retargets to chargers up
    to 60 m away sent robots in aisles round long detours, from one blocked way into the
    next; 20 m helped there but cost the 30-robot config laps).
    ``retarget_shorter``: ... and only if that way is shorter than the rest of the path it
    waits on. ``charge_margin_priority``: robots that need a charger are ranked (for free
    chargers, and as base priority at intersections, renewed every cycle on the way) by
    their energy margin, battery minus the energy to drive to the charger, instead of by
    the battery they had when they asked (needs the policy's battery model).

    Side steps on a roadmap with cells (``docs/traffic.md``, "Why waits cannot become
    permanent deadlocks"): ``sidestep_clear_corridor`` (path nodes, 0 = off): a robot
    stepping aside stops on a single-lane corridor node (degree 2: an aisle's node or a cut
    edge's cell) that another robot's next this many path nodes step onto only when no
    member of the deadlock has another side step (it stood in that robot's way at
    an aisle's first cell, each waiting for the other's node). ``sidestep_deep_depth`` (0 =
    off): when no member of a deadlock can reroute or step aside within ``sidestep_depth``
    edges, a member may step aside up to this many edges away before a robot outside the
    deadlock is moved.

    ``junction_with_corridor`` (corridor nodes, 0 = off): a robot whose next block is a
    junction followed on its path by a single-lane corridor in which another robot drives
    towards that junction asks for the junction and the corridor's block together, all or
    nothing, when that block has at least this many nodes (2 or 3 leave out the short cut
    edges between the junctions of a cross corridor)
    (:func:`fleet.traffic.grants.block`), instead of taking the junction and then waiting at
    it for the corridor while the robot leaving the corridor waits for the junction.
    ``swap_detect_s`` (``None`` = off): two robots that waited this long only on each other,
    each asking for a block that holds the node the other stands on (head-on, neither can
    move), are resolved like a deadlock without waiting ``deadlock_detect_s``
    (:func:`fleet.traffic.deadlocks.head_on_pairs`).
    """

    robot_radius: float = 0.3
    clearance_m: float | None = None
    arrive_m: float = 0.5
    horizon_m: float = 6.0
    progress_m: float = 0.1
    stall_timeout_s: float = 20.0
    stale_timeout_s: float | None = None
    deadlock_detect_s: float = 2.0
    detect_period_s: float = 0.5
    starve_s: float = 20.0
    reroute_after_s: float = 5.0
    reroute_factor: float = 2.0
    reroute_slack_m: float = 10.0
    sidestep_depth: int = 4
    yield_timeout_s: float = 30.0
    yield_bonus: float = 30.0
    aging_per_s: float = 1.0
    loop_min_nodes: int = 40
    max_resolutions: int = 8
    hold_far_end: bool = False
    follow: bool = True
    flow_penalty: float = 3.0
    turn_back: bool = True
    turn_back_m: float = 1.5
    dead_wait_s: float = 30.0
    cell_m: float | None = None
    charge_where_stepped: bool = False
    retarget_reach_m: float = 60.0
    retarget_shorter: bool = False
    charge_margin_priority: bool = False
    sidestep_clear_corridor: int = 0
    sidestep_deep_depth: int = 0
    contraflow_m: float = 0.0
    junction_with_corridor: int = 0
    swap_detect_s: float | None = None

    @property
    def clearance(self) -> float:
        """``clearance_m``, or its default ``2 * robot_radius + 0.3`` (m)."""
        return self.clearance_m if self.clearance_m is not None else 2.0 * self.robot_radius + 0.3
