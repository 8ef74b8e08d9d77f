"""Zenoh key expressions of the fleet: ``fleet/<robot>/status``, ``task``, ``grant``,
``alive`` and the navigation protocol's ``fleet/<robot>/nav/...`` keys."""

from __future__ import annotations

from fleet.errors import BackendError
from fleet.messages import (
    check_robot_name,
)

STATUS_KEYS = "fleet/*/status"


ALIVE_KEYS = "fleet/*/alive"


#: Status batches of every process (:mod:`fleet.messages.status_batch`); four chunks, so
#: ``fleet/*/status`` never matches them.
STATUS_BATCH_KEYS = "fleet/batch/*/status"


def status_batch_key(source: str) -> str:
    """``fleet/batch/<source>/status``: the status batches of the process named ``source``."""
    return f"fleet/batch/{check_robot_name(source)}/status"


def status_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/status"


def task_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/task"


def grant_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/grant"


def alive_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/alive"


def robot_of_key(key: str) -> str:
    """``robot3`` for ``fleet/robot3/status`` (the second chunk); ValueError if none."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != "fleet" or not parts[1]:
        raise ValueError(f"key {key!r} is not fleet/<robot>/...")
    return parts[1]


CLOCK_KEY = "fleet/sim/clock"

#: The fleet's control state (:class:`fleet.messages.FleetControl`): coordinator -> everyone.
CONTROL_KEY = "fleet/control/state"

#: The task service's key space (``docs/service.md``): queryables under it, task events on
#: ``fleet/service/events/<task id>``.
SERVICE_PREFIX = "fleet/service"


def robot_key_name(namespace: str) -> str:
    """``robot1`` for ``/robot1``."""
    name = namespace.strip("/")
    if not name:
        raise BackendError(f"bad robot namespace {namespace!r}")
    return name


def nav_key(namespace: str, what: str) -> str:
    """``fleet/<robot>/nav/<what>`` with ``what`` in ``goal``, ``cancel``, ``state``."""
    return f"fleet/{robot_key_name(namespace)}/nav/{what}"
