"""Driving a :class:`~fleet.traffic.manager.TrafficManager` without a simulator, for the
traffic rule tests: every 0.1 s each robot jumps to the first node of its grant."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from fleet.traffic.manager import TrafficManager
from fleet.types import Pose2D


def hop_to_goals(
    tm: TrafficManager,
    goals: Mapping[str, str],
    until_s: float,
    *,
    after_cycle: Callable[[float], None] | None = None,
    on_hop: Callable[[str, str], None] | None = None,
) -> float:
    """Cycle ``tm`` every 0.1 simulated s and move each robot of ``goals`` (robot -> its last
    node) to the first node of its grant, until every robot is done at its goal: the time
    that happened (``until_s`` if it did not). ``after_cycle(t)`` is called after each cycle,
    ``on_hop(robot, node)`` before each move."""
    t = 0.0
    while t < until_s:
        tm.cycle(t)
        if after_cycle is not None:
            after_cycle(t)
        for name in goals:
            nodes = tm.grant(name).nodes
            if nodes:
                if on_hop is not None:
                    on_hop(name, nodes[0])
                tm.update(name, Pose2D(*tm.node_pos(nodes[0]), 0.0), t)
        tm.check()
        if all(tm.done(n) and tm.path(n)[-1] == goal for n, goal in goals.items()):
            return t
        t = round(t + 0.1, 6)
    return until_s
