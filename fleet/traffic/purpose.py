"""Why a robot drives, as the traffic policy stamps it on :attr:`fleet.messages.Grant.purpose`."""

from __future__ import annotations

from enum import StrEnum


class Purpose(StrEnum):
    """The errand a grant serves (a robot without one gets ``""`` on its grant).

    ``PATROL``: its patrol loop; ``TASK``: once through a task's stops (a pick, a go_to, an
    inspection); ``CHARGE``: to a free charger dock; ``CHARGE_WAIT``: to a
    parking dock near the chargers, to wait for a charger; ``PARK``: idle, to a parking dock.
    """

    PATROL = "patrol"
    TASK = "task"
    CHARGE = "charge"
    CHARGE_WAIT = "charge-wait"
    PARK = "park"


#: Base priority of a robot that needs a charger (times ``2 - battery``): it outranks any
#: waiting robot, so it is not the one asked to yield on the way to the charger.
CHARGE_PRIORITY = 1000.0

#: A robot that needs a charger is sent to a free one at most this much (m, driving with the flow)
#: farther than its nearest charger; otherwise it waits for one near it: a charger frees
#: within about a minute (a charge from 30 % takes 33 s at 0.02 /s), a trip across a wide
#: floor costs minutes in traffic and energy the robot may not have.
CHARGE_REACH_M = 30.0
#: (The battery guard of a traffic-managed robot measures its trip with the same bound:
#: :class:`nodes.trees.ChargeThreshold`.)
