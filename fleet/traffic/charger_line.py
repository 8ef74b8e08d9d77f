"""Next in line for a busy charger (``TrafficParams.next_in_line``, ``docs/traffic.md``).

A charger dock is reserved for the robot heading to it from the moment it is sent, and stays
so while the robot charges. On a floor with few chargers a robot that must charge therefore
often finds none free, and used to wait on a parking dock near the chargers first: on the
6-robot warehouse 35 of 49 trips to a charger went that way, 36 m against 24 m for a trip
straight to a charger (``bench/traffic_time.py``). A robot that would only get to such a
dock after the robot charging on a charger near it is done is better sent straight to that
charger: it arrives as the charger frees, and the robot there leaves it at once.

:func:`next_charger` picks that charger; :class:`fleet.traffic.errands.Errands` sends the
robot, keeps its target while the robot it queued behind still stands on the dock, and
sends that robot off the dock as soon as it is done."""

from __future__ import annotations

from collections.abc import Mapping

from fleet.robots import BatteryModel

#: A charger counts as freeing before a robot gets there only if it frees this much (s)
#: earlier than the robot's drive at ``cruise_mps`` takes: the robot on it still has to
#: drive off its spur, and robots drive faster than ``cruise_mps`` where nobody is in the
#: way, so a smaller margin leaves robots waiting before the charger's junction, in the
#: way of the patrols.
MARGIN_S = 15.0


def frees_in(battery: float, model: BatteryModel) -> float:
    """Seconds until a robot charging at ``battery`` (fraction) reaches ``model.resume``."""
    return max(0.0, model.resume - battery) / model.charge_per_s


def next_charger(
    costs: Mapping[str, float],
    charging: Mapping[str, float],
    model: BatteryModel,
    margin_s: float = MARGIN_S,
) -> str | None:
    """The charger a robot should queue on, or ``None``.

    ``costs``: roadmap cost (m, with the flow) from the robot to each charger it may use;
    ``charging``: battery (fraction) of the robot charging on each busy charger that nobody
    is queued for yet. The answer is the charger of ``charging`` that frees soonest
    (:func:`frees_in`; ties: the least name) among those that free at least ``margin_s``
    before the robot gets there at ``model.cruise_mps``; ``None`` when none does (the robot then waits for a
    charger elsewhere)."""
    best: tuple[float, str] | None = None
    for charger, battery in charging.items():
        cost = costs.get(charger)
        if cost is None:
            continue
        frees = frees_in(battery, model)
        if frees + margin_s <= cost / model.cruise_mps and (best is None or (frees, charger) < best):
            best = (frees, charger)
    return None if best is None else best[1]
