"""Backend conformance harnesses: the registry every NavigationBackend plugs into.

(``conftest.py`` next to this file loads the plugins and defines the ``harness`` fixture.)

``test_backend_conformance.py`` runs each of its tests once per entry of
:data:`BACKEND_FACTORIES`. An entry maps a name to a *factory*: a zero-argument callable
returning a context manager that yields a :class:`ConformanceHarness` and tears everything
down on exit (close sessions, stop processes). A harness has:

* ``backend``: the :class:`fleet.navigation.NavigationBackend` under test, driving one robot
  that starts at ``world.start`` in a small known world;
* ``world``: a :class:`ConformanceWorld` naming a reachable pose, an occupied pose, an
  off-map pose, an unreachable (enclosed) pose, the free distance behind the start and the
  goal-checker tolerances of the backend;
* ``advance(seconds)``: let ``seconds`` of the backend's time pass. A simulated backend steps
  its simulator; a real-time backend (ROS 2 adapter, Zenoh bridge to a simulator running in
  another process) sleeps and spins its executor for that long.

Registering another backend (ROS 2 adapter, Zenoh bridge, SUMO): do **not** edit this file.
Create ``tests/conformance/harness_<name>.py`` defining a factory decorated with
:func:`register_backend`::

    from contextlib import contextmanager
    import pytest
    from conformance_harness import ConformanceWorld, register_backend

    @register_backend("zenoh_bridge", marks=(pytest.mark.slow,))
    @contextmanager
    def zenoh_bridge_harness():
        pytest.importorskip("zenoh")          # skip cleanly when a dependency is missing
        ...start the simulator process / bridge, build the backend...
        try:
            yield MyHarness(backend=..., world=SIM_WORLD, advance=...)
        finally:
            ...close everything...

``conftest.py`` imports every ``harness_*.py`` file next to it (sorted by name) before the
``harness`` fixture is parametrized, so a new file is picked up with no other change. A
factory may call ``pytest.skip`` to skip its backend on machines that lack it. The world of
the in-process simulator is :data:`SIM_WORLD` built by :func:`conformance_grid`; a backend
that wraps the simulator (e.g. the Zenoh bridge) should reuse both so the expectations match.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from fleet.clock import SimClock
from fleet.maps import OCCUPIED, OccupancyGrid
from fleet.navigation import NavigationBackend
from fleet.robots import RobotSpec, SimParams
from fleet.types import Pose2D
from sim.simulator import Simulator


@dataclass(frozen=True)
class ConformanceWorld:
    """What a conformance test may assume about the harness's world (``map`` frame, m, rad).

    ``reachable`` is free and reachable from ``start`` within ``nav_time_s`` seconds;
    ``occupied`` lies inside a static obstacle (GOAL_OCCUPIED); ``off_map`` is outside the map
    (GOAL_OUTSIDE_MAP); ``unreachable`` is free but enclosed (NO_VALID_PATH);
    ``free_behind_m`` is the free straight distance behind ``start`` (for BackUp).
    ``goal_tolerance`` / ``yaw_tolerance`` are the backend's goal-checker tolerances.
    """

    start: Pose2D
    reachable: Pose2D
    occupied: Pose2D
    off_map: Pose2D
    unreachable: Pose2D
    free_behind_m: float
    goal_tolerance: float
    yaw_tolerance: float
    nav_time_s: float = 60.0


class ConformanceHarness(Protocol):
    """One robot behind a backend under test, in a known world. See the module docstring."""

    @property
    def backend(self) -> NavigationBackend: ...

    @property
    def world(self) -> ConformanceWorld: ...

    def advance(self, seconds: float) -> None: ...


HarnessFactory = Callable[[], AbstractContextManager[ConformanceHarness]]

#: name -> factory; extend with :func:`register_backend` from a ``harness_<name>.py`` file.
BACKEND_FACTORIES: dict[str, HarnessFactory] = {}
_MARKS: dict[str, tuple[Any, ...]] = {}

#: Capabilities a conformance test may require with ``@pytest.mark.requires("<capability>")``.
#: A backend that declares it ``lacks`` one (with the reason) is not tested for it: the pair
#: is never generated, so nothing is skipped, and the reason is documented in one place.
CAPABILITIES = {
    "occupancy_map": "knows static obstacles, so a goal inside one aborts with GOAL_OCCUPIED",
    "spin_in_place": "can turn on the spot (Spin)",
    "reverse": "can drive backwards (BackUp)",
}
LACKS: dict[str, dict[str, str]] = {}


def register_backend(
    name: str, marks: tuple[Any, ...] = (), lacks: dict[str, str] | None = None
) -> Callable[[HarnessFactory], HarnessFactory]:
    """Decorator registering ``factory`` under ``name`` (with optional pytest marks).

    ``lacks`` maps capability names from :data:`CAPABILITIES` to the reason the backend
    cannot provide them; tests requiring those capabilities are not generated for it.
    """
    unknown = set(lacks or {}) - set(CAPABILITIES)
    if unknown:
        raise ValueError(f"conformance backend {name!r}: unknown capabilities {sorted(unknown)}")

    def deco(factory: HarnessFactory) -> HarnessFactory:
        if name in BACKEND_FACTORIES:
            raise ValueError(f"conformance backend {name!r} registered twice")
        BACKEND_FACTORIES[name] = factory
        _MARKS[name] = tuple(marks)
        LACKS[name] = dict(lacks or {})
        return factory

    return deco


def wait_for(
    harness: ConformanceHarness, predicate: Callable[[], bool], timeout_s: float, step_s: float = 0.1
) -> bool:
    """Advance the harness in ``step_s`` increments until ``predicate()`` holds or
    ``timeout_s`` of backend time passed; return whether it held."""
    waited = 0.0
    while not predicate():
        if waited >= timeout_s - 1e-9:
            return False
        harness.advance(step_s)
        waited += step_s
    return True


# ---------------------------------------------------------------------------
# The in-process simulator ("sim")
# ---------------------------------------------------------------------------


def conformance_grid() -> OccupancyGrid:
    """A 12 x 8 m room (0.1 m cells, origin (0, 0)) with outer walls, a 1 x 4 m shelf
    block at x in [5, 6], y in [2, 6], and a closed 2 x 2 m box around (10, 6)."""
    res = 0.1
    cells = np.zeros((80, 120), dtype=np.int8)
    cells[0, :] = cells[-1, :] = OCCUPIED
    cells[:, 0] = cells[:, -1] = OCCUPIED
    cells[20:60, 50:60] = OCCUPIED
    # enclosed box: walls of a 2 x 2 m square centered at (10, 6)
    cells[50:71, 90] = cells[50:71, 110] = OCCUPIED
    cells[50, 90:111] = cells[70, 90:111] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=res, origin_x=0.0, origin_y=0.0, source="<conformance>")


SIM_PARAMS = SimParams()
SIM_WORLD = ConformanceWorld(
    start=Pose2D(2.0, 4.0, 0.0),
    reachable=Pose2D(8.5, 4.0, math.pi / 2),
    occupied=Pose2D(5.5, 4.0, 0.0),
    off_map=Pose2D(-3.0, 4.0, 0.0),
    unreachable=Pose2D(10.0, 6.0, 0.0),
    free_behind_m=1.5,
    goal_tolerance=SIM_PARAMS.goal_tolerance,
    yaw_tolerance=SIM_PARAMS.yaw_tolerance,
)


@dataclass
class SimHarness:
    """Harness for :class:`sim.backend.NamespacedBackend`: ``advance`` steps the simulator."""

    sim: Simulator
    backend: NavigationBackend
    world: ConformanceWorld

    def advance(self, seconds: float) -> None:
        for _ in range(max(1, int(round(seconds / self.sim.params.step_s)))):
            self.sim.step()


@register_backend("sim")
@contextmanager
def sim_harness() -> Iterator[ConformanceHarness]:
    sim = Simulator(conformance_grid(), SIM_PARAMS, SimClock())
    sim.add_robot(RobotSpec("robot1", "/robot1", SIM_WORLD.start))
    yield SimHarness(sim, sim.backend("/robot1"), SIM_WORLD)
