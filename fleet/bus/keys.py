"""Zenoh key expressions of the fleet: ``fleet/<robot>/status``, ``task``, ``grant``,
``alive`` and the navigation protocol's ``fleet/<robot>/nav/...`` keys, and :data:`ACCESS`,
the one table of which role uses which key (the router's access control under ``--secure``
is generated from it alone: a new key goes into this table, see ``docs/security.md``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from fleet.errors import BackendError
from fleet.messages import (
    check_robot_name,
)

#: Templates of the per-robot keys (``{robot}`` is the robot's name, one key chunk).
STATUS = "fleet/{robot}/status"
TASK = "fleet/{robot}/task"
GRANT = "fleet/{robot}/grant"
ALIVE = "fleet/{robot}/alive"
NAV = "fleet/{robot}/nav/{what}"

STATUS_KEYS = STATUS.format(robot="*")


ALIVE_KEYS = ALIVE.format(robot="*")
#: An agent process's claim on its robot while it starts (``fleet/<robot>/agent/<session id>``,
#: docs/protocol.md "Leases"): of two agents started at once, both see both and step back.
AGENT_CLAIM = "fleet/{robot}/agent/{owner}"


#: Status batches of every process (:mod:`fleet.messages.status_batch`); four chunks, so
#: ``fleet/*/status`` never matches them.
STATUS_BATCH_KEYS = "fleet/batch/*/status"

#: The key space of a load test's lockstep protocol between its main process and its agent
#: workers (:mod:`fleet.loadtest.lockstep`): ``<prefix>/<run>/spec`` and ``<prefix>/<run>/nav``
#: (queries the main process answers), ``<prefix>/<run>/w<i>/tick`` and ``.../done``.
LOCKSTEP_PREFIX = "fleet/loadtest"


def status_batch_key(source: str) -> str:
    """``fleet/batch/<source>/status``: the status batches of the process named ``source``."""
    return f"fleet/batch/{check_robot_name(source)}/status"


def status_key(robot: str) -> str:
    return STATUS.format(robot=check_robot_name(robot))


def task_key(robot: str) -> str:
    return TASK.format(robot=check_robot_name(robot))


def grant_key(robot: str) -> str:
    return GRANT.format(robot=check_robot_name(robot))


def alive_key(robot: str) -> str:
    return ALIVE.format(robot=check_robot_name(robot))


def agent_claim_key(robot: str, owner: str = "*") -> str:
    return AGENT_CLAIM.format(robot=check_robot_name(robot), owner=owner)


def robot_of_key(key: str) -> str:
    """``robot3`` for ``fleet/robot3/status`` (the second chunk); ValueError if none."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != "fleet" or not parts[1]:
        raise ValueError(f"key {key!r} is not fleet/<robot>/...")
    return parts[1]


CLOCK_KEY = "fleet/sim/clock"

#: Every coordinator lease token (``fleet/coordinator/lease/<epoch>/<owner>``, docs/protocol.md).
LEASE_KEYS = "fleet/coordinator/lease/**"
#: Every simulator lease token (``fleet sim``): ``fleet/sim/lease/<owner>``.
SIM_LEASE_KEYS = "fleet/sim/lease/*"

#: The fleet's control state (:class:`fleet.messages.FleetControl`): coordinator -> everyone.
CONTROL_KEY = "fleet/control/state"

#: The task service's key space (``docs/service.md``): queryables under it, task events on
#: ``fleet/service/events/<task id>``.
SERVICE_PREFIX = "fleet/service"

#: Task events of the task service (``fleet/service/events/<task id>``).
SERVICE_EVENTS = f"{SERVICE_PREFIX}/events/*"

#: The task service's read-only queryables (what an observer may ask).
SERVICE_READS = (
    f"{SERVICE_PREFIX}/tasks",
    f"{SERVICE_PREFIX}/tasks/*",
    f"{SERVICE_PREFIX}/robots",
    f"{SERVICE_PREFIX}/fleet",
)

#: Key chunks the fleet uses itself: no robot may be named like one (``fleet/sim/clock``...).
RESERVED_CHUNKS = frozenset({"sim", "control", "service"})


def robot_key_name(namespace: str) -> str:
    """``robot1`` for ``/robot1``."""
    name = namespace.strip("/")
    if not name:
        raise BackendError(f"bad robot namespace {namespace!r}")
    return name


def nav_key(namespace: str, what: str) -> str:
    """``fleet/<robot>/nav/<what>`` with ``what`` in ``goal``, ``cancel``, ``state``."""
    return NAV.format(robot=robot_key_name(namespace), what=what)


# -- who uses which key (the access-control table) -----------------------------------------

#: How a process uses a key expression: ``put`` publishes on it, ``subscribe`` receives its
#: puts, ``token`` holds a liveliness token on it, ``watch`` watches liveliness tokens on it
#: (with history), ``serve`` answers queries on it (a queryable), ``query`` asks it.
Use = Literal["put", "subscribe", "token", "watch", "serve", "query"]

#: The roles of processes on the bus (``fleet keys init`` makes one identity per robot and
#: one of each other role).
Role = Literal["robot", "coordinator", "simulator", "observer", "worker"]


@dataclass(frozen=True)
class KeyUse:
    """``use`` of the key expression ``key``; in the ``robot`` role ``{robot}`` in ``key``
    stands for the identity's own robot name."""

    use: Use
    key: str


_ME = "{robot}"


def _nav(what: str, robot: str = _ME) -> str:
    return NAV.format(robot=robot, what=what)


#: What each role does on the bus, and nothing more (``--secure`` denies everything else).
#: The agent's process also subscribes to ``fleet/*/status`` for its report; under
#: ``--secure`` it sees only its own robot there (its session delivers its own puts).
ACCESS: dict[Role, tuple[KeyUse, ...]] = {
    "robot": (
        KeyUse("put", STATUS),
        KeyUse("token", ALIVE),
        KeyUse("token", AGENT_CLAIM.format(robot=_ME, owner="*")),
        KeyUse("watch", AGENT_CLAIM.format(robot=_ME, owner="*")),
        KeyUse("put", _nav("goal")),
        KeyUse("put", _nav("cancel")),
        KeyUse("subscribe", _nav("state")),
        KeyUse("subscribe", TASK),
        KeyUse("subscribe", GRANT),
        KeyUse("subscribe", CLOCK_KEY),
        KeyUse("subscribe", CONTROL_KEY),
        KeyUse("watch", ALIVE),
        KeyUse("watch", LEASE_KEYS),
        KeyUse("watch", SIM_LEASE_KEYS),
    ),
    "coordinator": (
        KeyUse("subscribe", STATUS_KEYS),
        KeyUse("watch", ALIVE_KEYS),
        KeyUse("put", TASK.format(robot="*")),
        KeyUse("put", GRANT.format(robot="*")),
        KeyUse("put", CONTROL_KEY),
        KeyUse("subscribe", CLOCK_KEY),
        KeyUse("serve", f"{SERVICE_PREFIX}/**"),
        KeyUse("put", SERVICE_EVENTS),
        KeyUse("token", LEASE_KEYS),
        KeyUse("watch", LEASE_KEYS),
        KeyUse("watch", SIM_LEASE_KEYS),
    ),
    "simulator": (
        KeyUse("subscribe", _nav("goal", "*")),
        KeyUse("subscribe", _nav("cancel", "*")),
        KeyUse("put", _nav("state", "*")),
        KeyUse("put", CLOCK_KEY),
        KeyUse("subscribe", CONTROL_KEY),
        KeyUse("token", SIM_LEASE_KEYS),
    ),
    "observer": (
        KeyUse("subscribe", STATUS_KEYS),
        KeyUse("watch", ALIVE_KEYS),
        KeyUse("watch", LEASE_KEYS),
        KeyUse("watch", SIM_LEASE_KEYS),
        KeyUse("subscribe", CONTROL_KEY),
        KeyUse("subscribe", SERVICE_EVENTS),
        *(KeyUse("query", k) for k in SERVICE_READS),
    ),
    # a load test's agent worker (`fleet loadtest --workers K --secure DIR`): its robots'
    # orders, states and goal calls travel in the lockstep protocol with the main process (the
    # router); on the bus it publishes the statuses and holds the liveliness of the robots it runs
    "worker": (
        KeyUse("subscribe", f"{LOCKSTEP_PREFIX}/*/*/tick"),
        KeyUse("put", f"{LOCKSTEP_PREFIX}/*/*/done"),
        KeyUse("query", f"{LOCKSTEP_PREFIX}/*/spec"),
        KeyUse("query", f"{LOCKSTEP_PREFIX}/*/nav"),
        KeyUse("put", STATUS_KEYS),
        KeyUse("token", ALIVE_KEYS),
    ),
}


def access_of(role: Role, robot: str | None = None) -> list[KeyUse]:
    """The key uses of ``role`` (for a robot, with ``{robot}`` filled in: ``robot`` required)."""
    uses = ACCESS[role]
    if role != "robot":
        return list(uses)
    if robot is None:
        raise ValueError("the robot role needs the robot's name")
    name = check_robot_name(robot)
    return [KeyUse(u.use, u.key.replace(_ME, name)) for u in uses]
