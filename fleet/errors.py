"""Exceptions for misuse and bad configuration. Expected runtime failures (a goal that
aborts, a robot that is stuck) are values, not exceptions: see :mod:`fleet.types`."""

from __future__ import annotations


class FleetError(Exception):
    """Base class of every exception this project raises on purpose."""


class ConfigError(FleetError):
    """A configuration file is invalid. The message names the file, the field and the reason.

    ``str(err)`` reads ``<file>: <field>: <reason>``, e.g.
    ``configs/bad.yaml: robots[2].start: pose (4.0, 7.5) is inside an obstacle``.
    """

    def __init__(self, file: str, field: str, reason: str) -> None:
        self.file = str(file)
        self.field = field
        self.reason = reason
        super().__init__(f"{self.file}: {field}: {reason}" if field else f"{self.file}: {reason}")


class MapError(ConfigError):
    """A map (map_server YAML + image) cannot be loaded or is inconsistent."""


class BackendError(FleetError):
    """A navigation backend was used wrongly or could not be set up (not a goal failure)."""


class BusError(FleetError):
    """The status bus could not be opened (bad endpoint, port in use, ...)."""


class LeaseError(BusError):
    """Another process already holds the exclusive lease this one needs (a second coordinator
    on the bus, a second agent for a robot). The message names the robot or the coordinator,
    the endpoint and the holder."""


class TrafficError(FleetError):
    """The traffic manager was used wrongly (unknown robot or node, bad path, bad parameter)."""


class DockError(FleetError):
    """A dock pose (parking spot, charger, robot start) cannot be joined to the roadmap."""


class TreeError(FleetError):
    """A behavior tree (BehaviorTree.CPP XML) cannot be loaded. The message names the file,
    the line, the node and the reason.

    ``str(err)`` reads ``<file>:<line>: <node>: <reason>``, e.g.
    ``trees/nav.xml:12: <Spinn>: unknown node 'Spinn'; did you mean Spin?``.
    """

    def __init__(self, file: str, line: int, node: str, reason: str) -> None:
        self.file = str(file)
        self.line = int(line)
        self.node = node
        self.reason = reason
        where = f"{self.file}:{self.line}" if self.line > 0 else self.file
        super().__init__(f"{where}: {node}: {reason}" if node else f"{where}: {reason}")


class ServiceError(FleetError):
    """A request to the task service cannot be carried out (``docs/service.md``)."""


class InvalidTask(ServiceError):
    """A task (or a command) is invalid; nothing was stored. ``str(err)`` reads
    ``<field>: <reason>``, e.g. ``waypoints[2]: unknown station or roadmap node 'a9_x'``."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}" if field else reason)


class UnknownTask(ServiceError):
    """No task has this id."""

    def __init__(self, task_id: str) -> None:
        self.task_id = task_id
        super().__init__(f"no task {task_id!r}")


class TaskFinished(ServiceError):
    """The task has already ended (completed, failed or canceled): it cannot be canceled."""

    def __init__(self, task_id: str, state: str) -> None:
        self.task_id = task_id
        self.state = state
        super().__init__(f"task {task_id!r} is already {state}")


class CommandRefused(ServiceError):
    """A fleet command cannot be applied now (e.g. ``resume`` while the e-stop is latched)."""


class ApiError(ServiceError):
    """An answer of a fleet's API with an error ``status`` (0: the fleet could not be
    reached), the ``field`` it is about and the ``reason``."""

    def __init__(self, status: int, reason: str, field: str = "") -> None:
        self.status = status
        self.reason = reason
        self.field = field
        where = f"{field}: " if field else ""
        super().__init__(f"{where}{reason}" + (f" (HTTP {status})" if status else ""))
