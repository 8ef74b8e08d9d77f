"""Roadmap travel distances from one node to every node, cached: the cost table behind task
matching (:mod:`fleet.coordination.matching`).

Distances are shortest-path lengths along the roadmap (m, the edges' ``length``), one compiled
Dijkstra per source node (:mod:`fleet.roadmap.dijkstra`: the same floats as networkx's). The
roadmap is read-only while a :class:`Distances` uses it.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from fleet.roadmap.dijkstra import Csr

if TYPE_CHECKING:
    from fleet.roadmap.graph import Roadmap

#: The rows a :class:`Distances` keeps, at most (bytes): 256 MB, so a 10,000-robot floor
#: (tens of thousands of nodes) does not keep gigabytes of rows.
CACHE_BYTES = 256 * 2**20

#: A row of distances (m), indexed like :attr:`Distances.index`; ``inf`` where unreachable.
DistanceRow = npt.NDArray[np.float64]


class Distances:
    """Shortest roadmap distances (m) from a source node to every node, as numpy rows.

    Args:
        roadmap: the roadmap (not modified).
        cache_rows: rows kept (least recently used dropped first), so memory stays bounded on a
            big roadmap: at most ``cache_rows * len(roadmap)`` floats, and never more than
            :data:`CACHE_BYTES` (fewer rows on a big roadmap; at least one).

    ``names`` are the roadmap's nodes in row order and ``index`` maps a node name to its column.
    """

    def __init__(self, roadmap: Roadmap, cache_rows: int = 4096) -> None:
        if cache_rows < 1:
            raise ValueError(f"Distances: cache_rows must be at least 1, got {cache_rows}")
        self.roadmap = roadmap
        self.names: list[str] = roadmap.nodes
        self.index: dict[str, int] = {n: i for i, n in enumerate(self.names)}
        self._rows: OrderedDict[str, DistanceRow] = OrderedDict()
        self._cap = max(1, min(cache_rows, CACHE_BYTES // (8 * max(1, len(self.names)))))
        self._csr: Csr | None = None  # built on the first row

    def row(self, source: str) -> DistanceRow:
        """Distances (m) from node ``source`` to every node (``inf``: unreachable). The row is
        shared with the cache: do not modify it. Raises ``KeyError`` for an unknown node."""
        r = self._rows.get(source)
        if r is not None:
            self._rows.move_to_end(source)
            return r
        if source not in self.index:
            raise KeyError(f"Distances.row: {source!r} is not a roadmap node")
        if self._csr is None:
            self._csr = Csr.of(self.roadmap.graph, self.names)
        r = self._csr.row(self.index[source])
        r.flags.writeable = False
        self._rows[source] = r
        if len(self._rows) > self._cap:
            self._rows.popitem(last=False)
        return r
