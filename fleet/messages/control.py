"""The fleet's control state on the bus (``fleet/control/state``): running, paused, or
emergency-stopped, with who changed it and when. Schema and semantics: ``docs/service.md``."""

from __future__ import annotations

from typing import Final

from msgspec import Struct

from fleet.messages.codec import Buffer, Codec, Count, Finite, Text, encode, to_builtins

#: ``running``: robots work; ``paused``: robots stand where they are and keep their tasks;
#: ``estop``: the emergency stop is latched (nothing moves until ``release``).
CONTROL_STATES: Final = ("running", "paused", "estop")


class FleetControl(Struct, frozen=True, tag_field="v", tag=1):
    """The fleet's control state.

    ``estop``: the emergency stop is latched; ``paused``: the fleet is paused (also true
    while latched, and after a release until ``resume``). ``seq`` increases with every change
    (a receiver applies only a newer one); ``t``: fleet time of the change (s); ``wall``: Unix
    time of the change (s); ``by``: who changed it; ``action``: the last command (``pause``,
    ``resume``, ``estop``, ``release`` or ``""``); ``reason``: free text.
    """

    estop: bool
    paused: bool
    seq: Count
    t: Finite = 0.0
    wall: Finite = 0.0
    by: Text = ""
    action: Text = ""
    reason: Text = ""

    @property
    def state(self) -> str:
        """One of :data:`CONTROL_STATES`."""
        return "estop" if self.estop else "paused" if self.paused else "running"

    def to_json(self) -> bytes:
        return encode(self, "control")

    def to_dict(self) -> dict[str, object]:
        d = to_builtins(self)
        d["state"] = self.state
        return d

    @classmethod
    def from_json(cls, data: Buffer) -> FleetControl:
        """Parse and validate; ValueError naming the bad field."""
        return CONTROL_CODEC.decode(data)


CONTROL_CODEC: Final = Codec(FleetControl, "control")
