"""The costmap services of one simulated robot (its lifecycle is :mod:`fleet.ros.lifecycle`).

* :class:`CostmapServices`: the clear services of Nav2's two costmaps, which really clear the
  robot's learned obstacles in the simulator (:mod:`sim.costmap`), and
  ``{global,local}_costmap/get_costmap``, which answer the live costmap.

Service names are relative, so they resolve under the robot's namespace
(``/robot1/global_costmap/get_costmap``). Callbacks run on the server's one executor thread.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from builtin_interfaces.msg import Time
from nav2_msgs.msg import Costmap
from nav2_msgs.srv import (
    ClearCostmapAroundPose,
    ClearCostmapAroundRobot,
    ClearCostmapExceptRegion,
    ClearEntireCostmap,
    GetCostmap,
)
from rclpy.node import Node

from fleet.ros.conversions import pose2d_to_pose, pose_stamped_to_pose2d
from fleet.types import Pose2D

if TYPE_CHECKING:
    from sim.costmap import CostmapRaster
    from sim.simulator import Simulator

#: The costmaps ``get_costmap`` is served for.
COSTMAPS = ("global_costmap", "local_costmap")


class CostmapServices:
    """The costmap services of one simulated robot ``namespace`` of ``sim``, served on ``node``
    with Nav2's names, for each of :data:`COSTMAPS` (``<costmap>/<service>_<costmap>``):

    * ``clear_entirely_<c>`` (ClearEntireCostmap): the learned obstacles of that costmap go;
    * ``clear_except_<c>`` (ClearCostmapExceptRegion): all but those in the square of side
      ``reset_distance`` around the robot;
    * ``clear_around_<c>`` (ClearCostmapAroundRobot): those in that square;
    * ``clear_around_pose_<c>`` (ClearCostmapAroundPose): those in the square around ``pose``;
    * ``get_costmap`` (GetCostmap): the live costmap (:meth:`sim.simulator.Simulator.costmap`):
      the whole map for the global one, a 5 m window around the robot for the local one;
      ``specs.layer`` picks ``static_layer``, ``obstacle_layer`` or ``inflation_layer``,
      anything else gives ``master`` (all layers).

    ``cleared`` counts the obstacles the clears removed. Callbacks run on the server's thread.
    """

    def __init__(self, node: Node, sim: Simulator, namespace: str, stamp: Callable[[], Time]) -> None:
        self._sim = sim
        self._ns = namespace
        self._stamp = stamp
        self.cleared = 0
        self.services = []
        for c in COSTMAPS:
            which = c.split("_")[0]
            self.services += [
                node.create_service(ClearEntireCostmap, f"{c}/clear_entirely_{c}", self._clear_entire(which)),
                node.create_service(
                    ClearCostmapExceptRegion, f"{c}/clear_except_{c}", self._clear_square(which, True)
                ),
                node.create_service(
                    ClearCostmapAroundRobot, f"{c}/clear_around_{c}", self._clear_square(which, False)
                ),
                node.create_service(
                    ClearCostmapAroundPose, f"{c}/clear_around_pose_{c}", self._clear_pose(which)
                ),
                node.create_service(GetCostmap, f"{c}/get_costmap", self._get_costmap(which)),
            ]

    def _clear_entire(self, which: str) -> Callable[[object, ClearEntireCostmap.Response], object]:
        def cb(_req: object, resp: ClearEntireCostmap.Response) -> object:
            self.cleared += self._sim.clear_costmaps(self._ns, which)
            return resp

        return cb

    def _clear_square(self, which: str, keep_inside: bool) -> Callable[[_Reset, object], object]:
        def cb(req: _Reset, resp: object) -> object:
            self.cleared += self._sim.clear_costmap_region(
                self._ns, which, float(req.reset_distance), keep_inside=keep_inside
            )
            return resp

        return cb

    def _clear_pose(self, which: str) -> Callable[[ClearCostmapAroundPose.Request, object], object]:
        def cb(req: ClearCostmapAroundPose.Request, resp: object) -> object:
            center = pose_stamped_to_pose2d(req.pose)
            self.cleared += self._sim.clear_costmap_region(
                self._ns, which, float(req.reset_distance), center=center
            )
            return resp

        return cb

    def _get_costmap(
        self, which: str
    ) -> Callable[[GetCostmap.Request, GetCostmap.Response], GetCostmap.Response]:
        def cb(req: GetCostmap.Request, resp: GetCostmap.Response) -> GetCostmap.Response:
            layer = str(req.specs.layer) if req.specs.layer in LAYERS else "master"
            raster = self._sim.costmap(self._ns, which, layer)
            resp.map = costmap_msg(raster, layer, self._stamp())
            return resp

        return cb


class _Reset(Protocol):
    reset_distance: float


#: The layers ``get_costmap`` serves by name (``master`` for any other).
LAYERS = ("static_layer", "obstacle_layer", "inflation_layer")


def costmap_msg(raster: CostmapRaster, layer: str, stamp: Time) -> Costmap:
    """A ``nav2_msgs/Costmap`` (frame ``map``) of a simulator costmap raster, row-major from
    its origin cell, as Nav2 publishes it."""
    m = Costmap()
    m.header.frame_id = "map"
    m.header.stamp = stamp
    m.metadata.layer = layer
    m.metadata.resolution = float(raster.resolution)
    rows, cols = raster.cost.shape
    m.metadata.size_x = int(cols)
    m.metadata.size_y = int(rows)
    m.metadata.origin = pose2d_to_pose(Pose2D(raster.origin_x, raster.origin_y, 0.0))
    m.metadata.update_time = stamp
    m.data = raster.cost.ravel().tolist()
    return m
