"""Every wire message of the fleet and its JSON codec; imports no Zenoh.

Messages are typed structs (msgspec) decoded strictly: a malformed payload raises
:class:`ValueError` naming the field and the reason (``status.battery: expected a finite
number, got 'x'``). Modules: :mod:`~fleet.messages.codec` (the decoding machinery, size
limits, field types), :mod:`~fleet.messages.records` (status records, task messages, picks,
traffic grants), :mod:`~fleet.messages.nav` (the navigation protocol between ``fleet sim``
and its clients, and the codec of goals, feedback, goal states and robot states). The
contract, with examples, is ``docs/status_bus.md``.
"""

from fleet.messages.codec import BUS_VERSION, DEFAULT_ENDPOINT, MAX_BRIDGE_PAYLOAD, MAX_PAYLOAD_BYTES
from fleet.messages.control import CONTROL_STATES, FleetControl
from fleet.messages.nav import (
    BRIDGE_VERSION,
    GOAL_KINDS,
    CancelRequest,
    ClockMsg,
    GoalRequest,
    NavState,
    goal_from_dict,
    goal_to_dict,
)
from fleet.messages.records import (
    STEP_KINDS,
    TASK_KINDS,
    Grant,
    PickLike,
    PickOrder,
    StatusRecord,
    TaskMessage,
    check_robot_name,
)
from fleet.messages.steps import ACTIONS, Action, Step

__all__ = [
    "ACTIONS",
    "CONTROL_STATES",
    "STEP_KINDS",
    "Action",
    "FleetControl",
    "Step",
    "BRIDGE_VERSION",
    "BUS_VERSION",
    "DEFAULT_ENDPOINT",
    "GOAL_KINDS",
    "MAX_BRIDGE_PAYLOAD",
    "MAX_PAYLOAD_BYTES",
    "TASK_KINDS",
    "CancelRequest",
    "ClockMsg",
    "GoalRequest",
    "Grant",
    "NavState",
    "PickLike",
    "PickOrder",
    "StatusRecord",
    "TaskMessage",
    "check_robot_name",
    "goal_from_dict",
    "goal_to_dict",
]
