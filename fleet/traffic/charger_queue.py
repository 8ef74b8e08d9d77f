"""Which robot gets which free charger (the charger queue of :mod:`fleet.traffic.errands`).

A free charger goes to the robot for which it matters:

* A robot is *urgent* when the battery it would have left on arrival at its nearest
  available charger, above ``reserve``, would not last one more charge of another robot
  (:func:`spare`: battery minus ``(1 + margin)`` times the trip's energy minus ``reserve``,
  below ``drain_per_s * resume / charge_per_s``). Urgent robots are served first, least
  spare first, each taking its nearest available charger.
* The other robots and chargers are paired nearest first (least roadmap cost of all
  remaining pairs): a robot 1 m from a charger takes it before one 17 m away with a lower
  battery that can afford to wait, and the charger frees again before that one would have
  arrived.

Everything here is a pure function of its arguments; ties go to the least name, so the
same requests give the same answer. Costs are roadmap costs in m (driving with the flow,
:meth:`fleet.traffic.manager.TrafficManager.costs_near`); batteries are fractions."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from fleet.robots import BatteryModel


@dataclass(frozen=True)
class ChargeNeed:
    """``robot`` (battery fraction ``battery``) needs a charger; ``costs``: the roadmap cost
    (m) from where it stands to each charger it may take now (free, or held by an idle robot
    that will leave it)."""

    robot: str
    battery: float
    costs: Mapping[str, float]


def trip_energy(model: BatteryModel, meters: float) -> float:
    """Battery fraction a drive of ``meters`` uses: ``drain_per_m`` per m and ``drain_per_s``
    over the drive at ``cruise_mps``."""
    d = max(0.0, meters)
    return model.drain_per_m * d + model.drain_per_s * d / model.cruise_mps


def spare(model: BatteryModel, battery: float, meters: float) -> float:
    """What is left above ``reserve`` after driving ``meters`` with ``1 + margin`` times the
    trip's energy set aside: ``battery - reserve - (1 + margin) * trip_energy``."""
    return battery - model.reserve - (1.0 + model.margin) * trip_energy(model, meters)


def urgent_below(model: BatteryModel) -> float:
    """The :func:`spare` below which a robot cannot wait for one full charge of another
    robot (``drain_per_s`` over ``resume / charge_per_s`` seconds)."""
    return model.drain_per_s * model.resume / model.charge_per_s


def assign_chargers(needs: Sequence[ChargeNeed], model: BatteryModel) -> dict[str, str]:
    """``{robot: charger}`` for the ``needs`` that get a charger now (module docstring); a
    charger goes to at most one robot, a robot gets one of its ``costs`` keys or none."""
    out: dict[str, str] = {}
    used: set[str] = set()
    limit = urgent_below(model)
    urgent: list[tuple[float, str, ChargeNeed]] = []
    for n in needs:
        if n.costs:
            s = spare(model, n.battery, min(n.costs.values()))
            if s < limit:
                urgent.append((s, n.robot, n))
    for _, robot, n in sorted(urgent, key=lambda u: (u[0], u[1])):
        left = [(c, ch) for ch, c in n.costs.items() if ch not in used]
        if left:
            _, ch = min(left)
            out[robot] = ch
            used.add(ch)
    pairs = sorted(
        (c, n.robot, ch) for n in needs if n.robot not in out for ch, c in n.costs.items() if ch not in used
    )
    for _, robot, ch in pairs:
        if robot not in out and ch not in used:
            out[robot] = ch
            used.add(ch)
    return out


__all__ = ["ChargeNeed", "assign_chargers", "spare", "trip_energy", "urgent_below"]
