"""What a robot agent needs of the bus: status out, orders and grants in, a liveliness token,
and (optionally) the fleet's control state. :class:`fleet.bus.status_bus.StatusBus` has it all;
tests pass smaller buses."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

from fleet.messages import FleetControl, Grant, StatusRecord, TaskMessage


class Declared(Protocol):
    """Something declared on the bus (a subscription, a liveliness token)."""

    def undeclare(self) -> None: ...


class AgentBus(Protocol):
    """What an agent needs of the bus (:class:`fleet.bus.status_bus.StatusBus` has it)."""

    def publish_status(self, rec: StatusRecord) -> None: ...

    def subscribe_tasks(self, robot: str, callback: Callable[[TaskMessage], None]) -> Declared: ...

    def subscribe_grants(self, robot: str, callback: Callable[[Grant], None]) -> Declared: ...

    def declare_alive(self, robot: str) -> Declared: ...


@runtime_checkable
class ControlBus(Protocol):
    """A bus that also carries the fleet's control state (:class:`StatusBus` does); an
    :class:`AgentBus` without it leaves pause and e-stop to in-process delivery."""

    def subscribe_control(self, callback: Callable[[FleetControl], None]) -> Declared: ...


__all__ = ["AgentBus", "ControlBus", "Declared"]
