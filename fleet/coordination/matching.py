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
* :class:`ChargerAllocation`: each robot is given a charger near its work: the charger of
  least roadmap travel distance from the task's nodes (their mean; the robot's own node when
  it has no task), plus :data:`SHARE_PENALTY_M` per robot already given that charger, so
  neighbours spread over the chargers around them and nobody is named a charger across the
  floor. A robot is given a charger anew when its work moves (a new task).
"""

from __future__ import annotations

import heapq
import math
from collections import OrderedDict
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

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
#: A charger already given to k robots looks k times this much (m) farther to the next robot:
#: about the length of a shelf row, so robots share the chargers at their end of the floor
#: rather than each taking the nearest one (a charger serves several robots: a working robot
#: spends about a fifth of its time charging).
SHARE_PENALTY_M = 12.0
#: How many distinct works' charger distances :class:`ChargerAllocation` remembers.
TRAVEL_MEMO = 4096

FloatArray = npt.NDArray[np.float64]

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
    unreachable.

    Tasks with the same entries (route copies) are priced once, and each task's padding (its
    last entry repeated up to the widest task) is left out: the cheapest entry (the first of
    equal ones) and its cost are those of pricing every padded entry of every task per robot
    (the code this replaced; ``tests/fleet/coordination/test_matching_scale.py`` keeps it as
    the reference), float for float. The widest task of a load-test floor (its perimeter
    loop, thousands of nodes) made the padded rows robots x tasks x thousands."""
    roadmap = distances.roadmap
    n_tasks, width = entry_idx.shape
    both = np.concatenate([entry_idx.astype(float), entry_off], axis=1)
    uniq, inverse = np.unique(both, axis=0, return_inverse=True)
    u_idx = uniq[:, :width].astype(np.int64)
    u_off = uniq[:, width:]
    # each unique task's entries without the padding (trailing copies of its last entry)
    same = (u_idx == u_idx[:, -1:]) & (u_off == u_off[:, -1:])
    lengths = width - np.argmin(same[:, ::-1], axis=1) + 1
    lengths[same.all(axis=1)] = 1
    keep = np.arange(width)[None, :] < lengths[:, None]
    flat_idx, flat_off = u_idx[keep], u_off[keep]
    seg = np.repeat(np.arange(len(uniq)), lengths)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    pos_in = np.arange(len(flat_idx)) - starts[seg]
    costs = np.full((len(poses), n_tasks), np.inf)
    entry = np.zeros((len(poses), n_tasks), dtype=np.int64)
    for i, pose in enumerate(poses):
        start = roadmap.nearest_node(pose.x, pose.y)
        sx, sy = roadmap.pos(start)
        d = distances.row(start)[flat_idx]
        snap = math.hypot(sx - pose.x, sy - pose.y)
        v = d + flat_off if offsets else d
        low = np.minimum.reduceat(v, starts)
        at = np.flatnonzero(v == low[seg])  # every entry at its task's minimum
        first = at[np.unique(seg[at], return_index=True)[1]]  # the first per task
        k = pos_in[first]
        c = snap + d[first] + flat_off[first] if offsets else snap + d[first]
        costs[i] = c[inverse]
        entry[i] = k[inverse]
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
    (row-major). Returns ``(row, column)`` pairs in matching order.

    The pairs and their order are those of taking the entries in the order of a stable sort of
    the whole matrix (the reference kept in ``tests/fleet/coordination/test_matching_scale.py``),
    without sorting it: each row offers its cheapest few columns (:data:`ROW_CANDIDATES`, ties
    at the last included), sorted by ``(rank, column)``; a heap merges the rows by ``(rank,
    flat index)``; a row whose offered columns are all taken offers twice as many of its
    cheapest free ones. Time about one pass over the matrix plus ``n log n``, instead of sorting ``rows x columns`` entries (10,000 x 10,000 for
    a 10,000-robot fleet's first assignment)."""
    n_rows, n_cols = ranks.shape
    pairs: list[tuple[int, int]] = []
    n = min(n_rows, n_cols)
    if n == 0:
        return pairs
    used_c = np.zeros(n_cols, dtype=bool)
    offers: list[list[int]] = [[] for _ in range(n_rows)]
    want = [ROW_CANDIDATES] * n_rows  # doubled at each refill: a row refills O(log columns) times
    heap: list[tuple[float, int, int]] = []  # (rank, flat index, row)
    for i in range(n_rows):
        _offer(ranks, i, used_c, offers, heap, want[i])
    while heap and len(pairs) < n:
        _, _, i = heapq.heappop(heap)
        j = offers[i].pop()
        if used_c[j]:
            if offers[i]:
                k = offers[i][-1]
                heapq.heappush(heap, (float(ranks[i, k]), i * n_cols + k, i))
            else:
                want[i] *= 2
                _offer(ranks, i, used_c, offers, heap, want[i])
            continue
        used_c[j] = True
        offers[i] = []
        pairs.append((i, j))
    return pairs


#: Columns each row first offers in :func:`greedy_match` (more when ranks tie at the last;
#: twice as many each time it offers again).
ROW_CANDIDATES = 8


def _offer(
    ranks: FloatMatrix,
    i: int,
    used_c: npt.NDArray[np.bool_],
    offers: list[list[int]],
    heap: list[tuple[float, int, int]],
    want: int,
) -> None:
    """Row ``i``'s cheapest finite free columns (all those ranked no higher than its
    ``want``-th), stacked cheapest last in ``offers[i]``; its first goes on the heap. A row
    with no finite free column offers nothing."""
    row = ranks[i]
    free = np.flatnonzero(~used_c & np.isfinite(row))
    if len(free) == 0:
        return
    vals = row[free]
    if len(free) > want:
        kth = np.partition(vals, want - 1)[want - 1]
        keep = vals <= kth
        free, vals = free[keep], vals[keep]
    order = np.lexsort((free, vals))  # by rank, then column
    offers[i] = [int(j) for j in free[order[::-1]]]
    k = offers[i][-1]
    heapq.heappush(heap, (float(row[k]), i * ranks.shape[1] + k, i))


class ChargerAllocation:
    """The charger of every robot (see the module docstring). ``poses`` are the chargers
    (map frame); a robot's charger is its :attr:`RobotView.charger` index. ``distances``: the
    roadmap's travel distances (without them, straight-line distance from the robot's pose).
    """

    def __init__(self, poses: Sequence[Pose2D], distances: Distances | None = None) -> None:
        self.poses = list(poses)
        self.load = [0] * len(self.poses)
        self._load = np.zeros(len(self.poses))  # ``load`` as floats, for the vectorized choice
        self._distances = distances
        #: Each charger's column in the ``distances`` rows (its nearest roadmap node).
        self.columns: list[int] = []
        if distances is not None:
            rm = distances.roadmap
            self.columns = [distances.index[rm.nearest_node(c.x, c.y)] for c in self.poses]
        #: The work (roadmap nodes) each robot's charger was chosen for.
        self._chosen_for: dict[str, tuple[str, ...]] = {}
        #: Mean travel distance to every charger, by the source nodes it was computed from
        #: (route copies share their work, so a fleet of thousands computes each once).
        self._travel_memo: OrderedDict[tuple[str, ...], FloatArray] = OrderedDict()
        #: The chargers in buckets (:func:`_cell`, for :meth:`on_charger`).
        self._cells: dict[tuple[int, int], list[Pose2D]] = {}
        for c in self.poses:
            self._cells.setdefault(_cell(c.x, c.y), []).append(c)

    def charger_for(self, v: RobotView, near: Sequence[str] = ()) -> Pose2D | None:
        """``v``'s charger pose (``None`` without chargers). Chosen now if ``v`` has none, or
        chosen again when ``near`` (the roadmap nodes of its new work) differs from the work
        it was chosen for; ``()`` keeps the charger it has."""
        if not self.poses:
            return None
        work = tuple(near)
        if v.charger is not None and (not work or self._chosen_for.get(v.name) == work):
            return self.poses[v.charger]
        if v.charger is not None:
            self._add(v.charger, -1)
        dist = self._travel(v, work)
        # the least ``dist[i] + SHARE_PENALTY_M * load[i]``, ties to the lower index
        best = int(np.argmin(dist + SHARE_PENALTY_M * self._load))
        v.charger = best
        self._add(best, 1)
        self._chosen_for[v.name] = work
        return self.poses[best]

    def _add(self, i: int, k: int) -> None:
        self.load[i] += k
        self._load[i] = self.load[i]

    def _travel(self, v: RobotView, work: tuple[str, ...]) -> FloatArray:
        """Distance (m) to every charger: mean roadmap distance from ``work``'s nodes (the
        robot's nearest node without work); straight line from the robot without a roadmap."""
        pose = v.obs.pose if v.obs is not None else None
        d = self._distances
        if d is None or not self.columns:
            return np.array([pose.distance_to(c) if pose is not None else 0.0 for c in self.poses])
        sources = tuple(n for n in work if n in d.index)
        if not sources and pose is not None:
            sources = (d.roadmap.nearest_node(pose.x, pose.y),)
        if not sources:
            return np.zeros(len(self.poses))
        known = self._travel_memo.get(sources)
        if known is not None:
            self._travel_memo.move_to_end(sources)
            return known
        total = np.zeros(len(self.columns))
        for n in sources:
            total += d.row(n)[self.columns]
        out = np.nan_to_num(total / len(sources), posinf=1e9)
        out.flags.writeable = False
        self._travel_memo[sources] = out
        if len(self._travel_memo) > TRAVEL_MEMO:
            self._travel_memo.popitem(last=False)
        return out

    def free(self, v: RobotView) -> None:
        """``v`` (dead) gives its charger back."""
        if v.charger is not None:
            self._add(v.charger, -1)  # both counts: the choice reads the array
            v.charger = None
        self._chosen_for.pop(v.name, None)

    def on_charger(self, v: RobotView) -> bool:
        """``v`` stands within :data:`ON_CHARGER_M` of a charger (only the chargers in the
        buckets around it are measured)."""
        pose = v.obs.pose if v.obs is not None else None
        if pose is None:
            return False
        ci, cj = _cell(pose.x, pose.y)
        return any(
            pose.distance_to(c) <= ON_CHARGER_M
            for i in (ci - 1, ci, ci + 1)
            for j in (cj - 1, cj, cj + 1)
            for c in self._cells.get((i, j), ())
        )


def _cell(x: float, y: float) -> tuple[int, int]:
    """The bucket (``2 * ON_CHARGER_M`` wide) of ``(x, y)``: a pose within
    :data:`ON_CHARGER_M` of a charger (rounding included) lies in the charger's bucket or one of
    the eight around it."""
    return (math.floor(x / (2 * ON_CHARGER_M)), math.floor(y / (2 * ON_CHARGER_M)))
