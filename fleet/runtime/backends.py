"""The registry of navigation backends by name (``fleet run --backend NAME``).

A backend is a *world factory*: ``factory(config, robots, session) -> World`` (see
:mod:`fleet.runtime.worlds`). Built-in entries name their factory as ``"module:attribute"``
and are imported only when used, so importing the core never imports rclpy or libsumo:

* ``sim``: the kinematic simulator, in this process;
* ``remote``: a simulator served by ``fleet sim`` in another process, over Zenoh;
* ``ros``: namespaced Nav2 robots over ROS 2 (``fleet sim-ros`` or real robots);
* ``sumo``: SUMO vehicles on the roadmap's network (libsumo).

Plug in another backend with :func:`register_backend`.
"""

from __future__ import annotations

import importlib

from fleet.errors import BackendError
from fleet.runtime.worlds import WorldFactory

#: Navigation backends by name: a factory, or the ``"module:attribute"`` path of one.
BACKENDS: dict[str, WorldFactory | str] = {
    "sim": "fleet.runtime.worlds:SimWorld",
    "remote": "fleet.runtime.worlds:RemoteWorld",
    "ros": "fleet.ros.world:RosWorld",
    "sumo": "sim.sumo.backend:SumoRunnerWorld",
}


def register_backend(name: str, factory: WorldFactory | str) -> None:
    """Make ``factory`` (or the ``"module:attribute"`` path of one) available as
    ``FleetRunner(backend=name)`` / ``fleet run --backend name``."""
    BACKENDS[name] = factory


def backend_names() -> list[str]:
    """The registered backend names, sorted."""
    return sorted(BACKENDS)


def world_factory(name: str) -> WorldFactory:
    """The world factory registered as ``name``, imported on first use. Raises
    :class:`BackendError` for an unknown name or a factory that cannot be imported (the message
    says what to install)."""
    entry = BACKENDS.get(name)
    if entry is None:
        raise BackendError(f"unknown backend {name!r}; known: {', '.join(backend_names())}")
    if not isinstance(entry, str):
        return entry
    module, _, attr = entry.partition(":")
    try:
        factory: WorldFactory = getattr(importlib.import_module(module), attr)
    except ImportError as e:
        raise BackendError(f"backend {name!r} cannot be loaded ({e}); see docs/cli.md for its setup") from e
    BACKENDS[name] = factory
    return factory
