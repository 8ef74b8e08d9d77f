"""Who gets what: travel costs from robots to tasks, the greedy min-cost matching, and the
charger each robot is given.

* :func:`travel_costs`: the cost (m) of robot ``i`` starting task ``j`` is the straight line
  from the robot's pose to its nearest roadmap node, plus the roadmap distance from there to
  the task's cheapest entry node, plus that entry's extra distance (e.g. node to shelf).
  One Dijkstra per distinct start node (cached by :class:`~fleet.roadmap.distances.Distances`)
  and numpy over the tasks, so 1000 robots x 1000 tasks is one matrix, not a million searches.
* :func:`greedy_match`: the cheapest (robot, task) pair first, then the next cheapest among
  the rest; infinite costs (unreachable) never match. :func:`rank` turns costs into the order
  the matcher uses: robots idling on a charger look :data:`CHARGER_BONUS_M` closer, robots in
  cool-down :data:`COOLDOWN_PENALTY` farther, a task's preferred robot comes first.
* :class:`ChargerAllocation`: each robot is given a charger when first needed: the
  least-loaded charger, nearest first among equally loaded ones, so two robots share a
  charger only when there are more robots than chargers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from fleet.coordination.tasks import FloatMatrix, IndexMatrix
from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.coordination.views import RobotView
    from fleet.roadmap.distances import Distances

#: Added to the travel cost (m) of a robot recently taken off a task for being stuck.
COOLDOWN_PENALTY = 1e6
#: Idle robots standing within ON_CHARGER_M (m) of a charger look this much (m) closer to
#: every task, so that they leave the charger to robots that need it.
CHARGER_BONUS_M = 20.0
ON_CHARGER_M = 0.5
#: The rank (m) of a task's preferred robot: below any travel cost, so it is matched first.
PREFERRED_RANK = -1e9
#: Each level of a task's priority lowers its rank by this much (m): a higher-priority task
#: is matched before any lower-priority one, whatever the distances.
PRIORITY_M = 1e6


def travel_costs(
    distances: Distances,
    poses: Sequence[Pose2D],
    entry_idx: IndexMatrix,
    entry_off: FloatMatrix,
    offsets: bool = True,
) -> tuple[FloatMatrix, IndexMatrix]:
    """Travel costs (m) ``[robot, task]`` from ``poses`` (one per robot, map frame) to tasks
    given by their entry nodes ``entry_idx[task, k]`` (indexes in ``distances``) and extra
    distances ``entry_off[task, k]``, and the entry ``k`` each robot would start at.
    ``offsets=False`` promises ``entry_off`` is all zeros (it is then skipped). ``inf``:
    unreachable."""
    roadmap = distances.roadmap
    n_tasks = entry_idx.shape[0]
    costs = np.full((len(poses), n_tasks), np.inf)
    entry = np.zeros((len(poses), n_tasks), dtype=np.int64)
    cols = np.arange(n_tasks)
    for i, pose in enumerate(poses):
        start = roadmap.nearest_node(pose.x, pose.y)
        sx, sy = roadmap.pos(start)
        d = distances.row(start)[entry_idx]
        snap = math.hypot(sx - pose.x, sy - pose.y)
        if offsets:
            k = np.argmin(d + entry_off, axis=1)
            costs[i] = snap + d[cols, k] + entry_off[cols, k]
        else:
            k = np.argmin(d, axis=1)
            costs[i] = snap + d[cols, k]
        entry[i] = k
    return costs, entry


def rank(
    costs: FloatMatrix,
    robots: Sequence[RobotView],
    preferred: Sequence[str | None],
    chargers: ChargerAllocation,
    now: float,
    priorities: Sequence[int] | None = None,
    only: Sequence[str | None] | None = None,
) -> FloatMatrix:
    """The matching order of ``costs[robot, task]`` (a copy): robots on a charger
    :data:`CHARGER_BONUS_M` lower, robots in cool-down (``now < cooldown_until``)
    :data:`COOLDOWN_PENALTY` higher, task ``j`` :data:`PRIORITY_M` lower per level of
    ``priorities[j]``, and the preferred robot of task ``j`` (``preferred[j]``, if among
    ``robots`` and the task is reachable for it) at :data:`PREFERRED_RANK` (minus its
    priority). ``only[j]``: the one robot task ``j`` may go to (every other robot: ``inf``)."""
    r = costs.copy()
    for i, v in enumerate(robots):
        if chargers.on_charger(v):
            r[i] -= CHARGER_BONUS_M
        if now < v.cooldown_until:
            r[i] += COOLDOWN_PENALTY
    if priorities is not None and any(priorities):
        r -= np.asarray(priorities, dtype=float)[None, :] * PRIORITY_M
    names = {v.name: i for i, v in enumerate(robots)}
    for j, pref in enumerate(preferred):
        if pref is not None and pref in names and math.isfinite(r[names[pref], j]):
            r[names[pref], j] = PREFERRED_RANK - (
                priorities[j] * PRIORITY_M if priorities is not None else 0.0
            )
    if only is not None:
        for j, name in enumerate(only):
            if name is None:
                continue
            keep = names.get(name)
            col = r[keep, j] if keep is not None else np.inf
            r[:, j] = np.inf
            if keep is not None:
                r[keep, j] = col
    return r


def greedy_match(ranks: FloatMatrix) -> list[tuple[int, int]]:
    """Greedy min-cost matching of rows (robots) to columns (tasks): the lowest finite entry
    first, then the lowest among the rows and columns left; ties go to the lower flat index
    (row-major). Returns ``(row, column)`` pairs in matching order."""
    n_rows, n_cols = ranks.shape
    pairs: list[tuple[int, int]] = []
    used_r: set[int] = set()
    used_c: set[int] = set()
    n = min(n_rows, n_cols)
    if n == 0:
        return pairs
    for f in np.argsort(ranks, axis=None, kind="stable"):
        i, j = divmod(int(f), n_cols)
        if i in used_r or j in used_c or not math.isfinite(ranks[i, j]):
            continue
        used_r.add(i)
        used_c.add(j)
        pairs.append((i, j))
        if len(pairs) == n:
            break
    return pairs


class ChargerAllocation:
    """The charger of every robot (see the module docstring). ``poses`` are the chargers
    (map frame); a robot's charger is its :attr:`RobotView.charger` index."""

    def __init__(self, poses: Sequence[Pose2D]) -> None:
        self.poses = list(poses)
        self.load = [0] * len(self.poses)

    def charger_for(self, v: RobotView) -> Pose2D | None:
        """``v``'s charger pose (``None`` without chargers); chosen now if it has none."""
        if not self.poses:
            return None
        if v.charger is None:
            pose = v.obs.pose if v.obs is not None else None
            best: tuple[int, float, int] | None = None
            for i, c in enumerate(self.poses):
                d = pose.distance_to(c) if pose is not None else 0.0
                key = (self.load[i], d, i)
                if best is None or key < best:
                    best = key
            assert best is not None
            v.charger = best[2]
            self.load[v.charger] += 1
        return self.poses[v.charger]

    def free(self, v: RobotView) -> None:
        """``v`` (dead) gives its charger back."""
        if v.charger is not None:
            self.load[v.charger] -= 1
            v.charger = None

    def on_charger(self, v: RobotView) -> bool:
        """``v`` stands within :data:`ON_CHARGER_M` of a charger."""
        pose = v.obs.pose if v.obs is not None else None
        return pose is not None and any(pose.distance_to(c) <= ON_CHARGER_M for c in self.poses)
