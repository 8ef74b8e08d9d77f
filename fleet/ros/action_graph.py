"""Which action servers each robot's namespace serves, read from the ROS graph node by node.

rclpy's ``ActionClient.server_is_ready()`` counts the matching endpoints of the action's three
services and two topics over the *whole* graph, eight scans of every endpoint the participant
has discovered, under the graph's lock (which the middleware's discovery thread needs too).
With 200 robots the graph holds about 30,000 endpoints, and checking every robot's seven
servers once a second kept the client's CPU busy and discovery waiting (``docs/ros.md``,
"Scale"). :func:`served_actions` reads the same facts per node instead: one pass over the
node list, then for each node in a robot's namespace only that node's own endpoints. A server
counts once its feedback publisher is discovered (rcl's by-node action query), which is
what a fleet needs to call a robot discovered; the send path still checks
``server_is_ready()`` for the one action it sends on.

Real Nav2 spreads the actions over ``bt_navigator``, ``behavior_server`` and
``waypoint_follower``; ``fleet sim-ros`` serves them from one ``nav2_sim`` node per robot:
both are found, whatever the node names, as long as the nodes live in the robot's namespace.
"""

from __future__ import annotations

from collections.abc import Iterable

from fleet.ros.env import apply_ros_env_defaults

apply_ros_env_defaults()

from rclpy.action.graph import get_action_server_names_and_types_by_node  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

#: Parameters of a node that should add as little to the graph as it can: no
#: ``~/get_type_description`` service (two DDS endpoints per node that a fleet never asks).
LEAN_NODE_PARAMETERS = [Parameter("start_type_description_service", value=False)]
#: The fleet client's own node names (``fleet.ros.backend``: they serve no action).
OWN_NODES = ("fleet_backend", "fleet_backends")


def served_actions(
    node: Node, namespaces: Iterable[str], skip_nodes: Iterable[str] = ()
) -> dict[str, frozenset[str]]:
    """For each namespace (``/robot1``), the relative names of the action servers
    (``navigate_to_pose``, ...) and services (``bt_navigator/get_state``, ...) that ``node``'s
    participant has discovered on nodes of exactly that namespace. Nodes named in ``skip_nodes`` (the caller's own, which serve nothing) are
    not asked. Thread-safe (the graph has its own lock); costs one pass over the node list
    plus the endpoints of the nodes in ``namespaces``."""
    wanted = {ns: set[str]() for ns in namespaces}
    skip = set(skip_nodes)
    for name, ns in node.get_node_names_and_namespaces():
        found = wanted.get(ns)
        if found is None or name in skip:
            continue
        prefix = ns.rstrip("/") + "/"
        for served, _types in [
            *get_action_server_names_and_types_by_node(node, name, ns),
            *node.get_service_names_and_types_by_node(name, ns),
        ]:
            if served.startswith(prefix):
                found.add(served[len(prefix) :])
    return {ns: frozenset(s) for ns, s in wanted.items()}
