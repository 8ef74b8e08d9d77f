"""The SUMO world as navigation backends for the runner: one backend per robot, and the
runner's world (``fleet run --backend sumo``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from fleet.clock import SimClock
from fleet.robots import RobotSpec
from sim.backend import NamespacedBackend
from sim.sumo.world import SumoWorld, active_world

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig


class SumoRunnerWorld:
    """The SUMO backend as a ``fleet.runtime.runner`` world (``WorldFactory`` signature).

    Every robot of ``config`` becomes a vehicle (like the simulator world, ``robots`` only
    selects agents elsewhere). Wire it with
    ``fleet.runtime.runner.register_backend("sumo", SumoRunnerWorld)`` (import lazily: this module
    loads libsumo when the world opens). A config whose roadmap is a SUMO network
    (``roadmap: {net: ...}``) drives on that ``.net.xml``; otherwise a network is generated
    from ``config.roadmap``.
    """

    remote = False

    def __init__(
        self,
        config: FleetConfig,
        robots: Sequence[RobotSpec] = (),
        session: object = None,
        **kw: Any,  # SumoWorld's keyword options, passed through
    ) -> None:
        self.clock = SimClock()
        self.step_s = float(config.sim.step_s)
        self.world = SumoWorld(config.roadmap, list(config.robots), config.sim, self.clock, **kw)

    def backend(self, namespace: str) -> NamespacedBackend:
        return self.world.backend(namespace)

    def advance(self) -> None:
        self.world.step()

    def collisions(self) -> int | None:
        return self.world.collisions

    @property
    def teleports(self) -> int:
        """Vehicles SUMO moved on after they waited too long (its deadlocks), so far."""
        return int(self.world.teleports)

    def collision_points(self) -> list[tuple[float, float]]:
        return [(x, y) for _, _, _, x, y in self.world.collision_events]

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]] | None:
        return self.world.trajectory(namespace)

    def close(self) -> None:
        self.world.close()


__all__ = ["SumoRunnerWorld", "active_world"]
