"""The registry of backend harnesses the conformance tests run on (pytest side).

(``conftest.py`` next to this file loads the plugins and parametrizes the tests.)

The cases themselves live in :mod:`fleet.testing.conformance` (``check_backend`` for users);
``test_backend_conformance.py`` runs each case once per entry of :data:`BACKEND_FACTORIES`, as
one pytest test per (backend, case). An entry maps a name to a *harness factory* (a
zero-argument callable returning a context manager that yields a
:class:`fleet.testing.conformance.ConformanceHarness` and tears everything down on exit).

Registering another backend: do **not** edit this file. Create ``harness_<name>.py`` next to
it defining a factory decorated with :func:`register_backend`::

    from contextlib import contextmanager
    import pytest
    from conformance_harness import register_backend

    @register_backend("zenoh_bridge", marks=(pytest.mark.slow,))
    @contextmanager
    def zenoh_bridge_harness():
        pytest.importorskip("zenoh")          # skip cleanly when a dependency is missing
        ...start the simulator process / bridge, build the backend...
        try:
            yield MyHarness(backend=..., world=SIM_WORLD, advance=...)
        finally:
            ...close everything...

``conftest.py`` imports every ``harness_*.py`` file here (sorted by name) before the tests are
parametrized. A factory may call ``pytest.skip`` to skip its backend on machines that lack it.
The world of the in-process simulator is :data:`fleet.testing.room.SIM_WORLD` (grid
:func:`fleet.testing.room.conformance_grid`); a backend that wraps the simulator (the Zenoh
bridge, the ROS 2 facade) reuses both so the expectations match.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from fleet.clock import SimClock
from fleet.navigation import NavigationBackend
from fleet.robots import RobotSpec
from fleet.testing.conformance import (
    CAPABILITIES,
    ConformanceHarness,
    ConformanceWorld,
    HarnessFactory,
    wait_for,
)
from fleet.testing.room import SIM_PARAMS, SIM_WORLD, conformance_grid
from sim.simulator import Simulator

__all__ = [
    "BACKEND_FACTORIES",
    "LACKS",
    "MARKS",
    "SIM_PARAMS",
    "SIM_WORLD",
    "ConformanceHarness",
    "ConformanceWorld",
    "conformance_grid",
    "register_backend",
    "wait_for",
]

#: name -> factory; extend with :func:`register_backend` from a ``harness_<name>.py`` file.
BACKEND_FACTORIES: dict[str, HarnessFactory] = {}
#: name -> pytest marks of its tests.
MARKS: dict[str, tuple[object, ...]] = {}
#: name -> capabilities of :data:`fleet.testing.conformance.CAPABILITIES` it lacks, with why.
LACKS: dict[str, dict[str, str]] = {}


def register_backend(
    name: str, marks: tuple[object, ...] = (), lacks: dict[str, str] | None = None
) -> Callable[[HarnessFactory], HarnessFactory]:
    """Decorator registering ``factory`` under ``name`` (with optional pytest marks).

    ``lacks`` maps capability names to the reason the backend cannot provide them; the cases
    requiring them are not generated for it.
    """
    unknown = set(lacks or {}) - set(CAPABILITIES)
    if unknown:
        raise ValueError(f"conformance backend {name!r}: unknown capabilities {sorted(unknown)}")

    def deco(factory: HarnessFactory) -> HarnessFactory:
        if name in BACKEND_FACTORIES:
            raise ValueError(f"conformance backend {name!r} registered twice")
        BACKEND_FACTORIES[name] = factory
        MARKS[name] = tuple(marks)
        LACKS[name] = dict(lacks or {})
        return factory

    return deco


# ---------------------------------------------------------------------------
# The in-process simulator ("sim")
# ---------------------------------------------------------------------------


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
