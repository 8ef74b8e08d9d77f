"""The Nav2 services of one simulated robot: lifecycle and costmaps.

* :class:`LifecycleServices`: ``<node>/get_state`` for each of :data:`LIFECYCLE_NODES`
  (answering ``active``: the simulator is always up) and
  ``lifecycle_manager_navigation/manage_nodes`` (every command succeeds). This is what
  ``BasicNavigator.waitUntilNav2Active()`` / ``lifecycleStartup()`` call.
* :class:`CostmapServices`: the four clear services of Nav2's costmaps (no-ops: the simulated
  costmaps hold only the static map) and ``{global,local}_costmap/get_costmap``, which answer
  the static map as a ``nav2_msgs/Costmap`` (:func:`costmap_from_grid`).

Service names are relative, so they resolve under the robot's namespace
(``/robot1/amcl/get_state``). Callbacks run on the server's one executor thread.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from lifecycle_msgs.msg import State
from lifecycle_msgs.srv import GetState
from nav2_msgs.msg import Costmap
from nav2_msgs.srv import (
    ClearCostmapAroundPose,
    ClearCostmapAroundRobot,
    ClearCostmapExceptRegion,
    ClearEntireCostmap,
    GetCostmap,
    ManageLifecycleNodes,
)
from rclpy.node import Node

from fleet.maps import FREE, OccupancyGrid
from fleet.ros.conversions import pose2d_to_pose
from fleet.types import Pose2D

#: Nav2 nodes whose lifecycle state a client may ask (``<name>/get_state``).
LIFECYCLE_NODES = (
    "bt_navigator",
    "amcl",
    "planner_server",
    "controller_server",
    "behavior_server",
    "map_server",
)
#: Nav2's lifecycle manager of the navigation nodes.
LIFECYCLE_MANAGER = "lifecycle_manager_navigation"
#: Cost of an occupied cell in a published costmap (Nav2's LETHAL_OBSTACLE).
LETHAL_COST = 254

#: Every clear service of Nav2's two costmaps: (service type, relative name).
CLEAR_SERVICES = (
    (ClearEntireCostmap, "global_costmap/clear_entirely_global_costmap"),
    (ClearEntireCostmap, "local_costmap/clear_entirely_local_costmap"),
    (ClearCostmapExceptRegion, "local_costmap/clear_costmap_except_region"),
    (ClearCostmapAroundRobot, "local_costmap/clear_costmap_around_robot"),
    (ClearCostmapAroundPose, "local_costmap/clear_costmap_around_pose"),
)
#: The costmaps ``get_costmap`` is served for.
COSTMAPS = ("global_costmap", "local_costmap")


class LifecycleServices:
    """Lifecycle services of one robot's Nav2 nodes, served on ``node``.

    Every node of :data:`LIFECYCLE_NODES` reports ``active``; ``manage_nodes`` accepts every
    command (startup, shutdown, pause, resume, reset) and reports success without changing
    anything.
    """

    def __init__(self, node: Node) -> None:
        self.services = [
            node.create_service(GetState, f"{name}/get_state", self._get_state) for name in LIFECYCLE_NODES
        ]
        self.services.append(
            node.create_service(ManageLifecycleNodes, f"{LIFECYCLE_MANAGER}/manage_nodes", self._manage)
        )

    def _get_state(self, _req: GetState.Request, resp: GetState.Response) -> GetState.Response:
        resp.current_state = State(id=State.PRIMARY_STATE_ACTIVE, label="active")
        return resp

    def _manage(
        self, _req: ManageLifecycleNodes.Request, resp: ManageLifecycleNodes.Response
    ) -> ManageLifecycleNodes.Response:
        resp.success = True
        return resp


class CostmapServices:
    """Costmap services of one robot, served on ``node``: the clears of
    :data:`CLEAR_SERVICES` (they answer and change nothing) and ``get_costmap`` of each of
    :data:`COSTMAPS`, answered with ``costmap()`` (the static map, built once by the
    server)."""

    def __init__(self, node: Node, costmap: Callable[[], Costmap]) -> None:
        self._costmap = costmap
        self.services = [node.create_service(srv, name, self._clear) for srv, name in CLEAR_SERVICES]
        self.services += [
            node.create_service(GetCostmap, f"{name}/get_costmap", self._get_costmap) for name in COSTMAPS
        ]

    def _clear(self, _req: object, resp: object) -> object:
        return resp

    def _get_costmap(self, _req: GetCostmap.Request, resp: GetCostmap.Response) -> GetCostmap.Response:
        resp.map = self._costmap()
        return resp


def costmap_from_grid(grid: OccupancyGrid) -> Costmap:
    """The ``nav2_msgs/Costmap`` (layer ``master``, frame ``map``) of an occupancy grid: free
    cells cost 0, every other cell :data:`LETHAL_COST`. Row-major from the origin cell, as
    Nav2 publishes it."""
    m = Costmap()
    m.header.frame_id = "map"
    m.metadata.layer = "master"
    m.metadata.resolution = float(grid.resolution)
    m.metadata.size_x = grid.width
    m.metadata.size_y = grid.height
    m.metadata.origin = pose2d_to_pose(Pose2D(grid.origin_x, grid.origin_y, 0.0))
    m.data = np.where(grid.cells == FREE, 0, LETHAL_COST).astype(np.uint8).ravel().tolist()
    return m
