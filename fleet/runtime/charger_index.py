"""The charger nearest a robot before the coordinator names one: one array pass over the
config's chargers instead of a Python ``min`` over them per robot (a 10,000-robot floor has
5000 chargers and every agent asks once)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from fleet.types import Pose2D

_Arrays = tuple[Sequence[Pose2D], npt.NDArray[np.float64], npt.NDArray[np.float64]]
#: The arrays of the charger sequences asked about, by identity (a fleet shares one).
_cache: dict[int, _Arrays] = {}


def nearest_charger(chargers: Sequence[Pose2D], pose: Pose2D) -> Pose2D:
    """The charger of least ``|dx| + |dy|`` from ``pose`` (m), ties to the lower ``x``, then the
    lower ``y``, then the earlier one: ``min(chargers, key=(|dx| + |dy|, x, y))``, with the
    same float operations. ``chargers`` must not be empty (and is not to be modified: its
    coordinates are kept as arrays while it lives)."""
    got = _cache.get(id(chargers))
    if got is None or got[0] is not chargers:
        if len(_cache) > 64:
            _cache.clear()
        xs = np.array([c.x for c in chargers], dtype=float)
        ys = np.array([c.y for c in chargers], dtype=float)
        got = _cache[id(chargers)] = (chargers, xs, ys)
    _, xs, ys = got
    d = np.abs(xs - pose.x) + np.abs(ys - pose.y)
    return chargers[int(np.lexsort((ys, xs, d))[0])]


__all__ = ["nearest_charger"]
