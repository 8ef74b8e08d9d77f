"""Roadmap distance rows: shortest paths along the roadmap, inf when unreachable, a bounded cache."""

from __future__ import annotations

import math

import pytest

from fleet.roadmap.distances import Distances
from fleet.roadmap.graph import Roadmap


def roadmap() -> Roadmap:
    return Roadmap.from_config_dict(
        {
            "nodes": {"a": [0, 0], "b": [3, 4], "c": [3, 0], "z": [50, 50]},
            "edges": [["a", "b"], ["b", "c"]],
        }
    )


def test_rows_are_shortest_roadmap_distances() -> None:
    d = Distances(roadmap())
    row = d.row("a")
    assert row[d.index["a"]] == 0.0
    assert row[d.index["b"]] == pytest.approx(5.0)
    assert row[d.index["c"]] == pytest.approx(9.0)  # along the roadmap, not the straight 3 m
    assert math.isinf(row[d.index["z"]])
    with pytest.raises(KeyError, match="'nope' is not a roadmap node"):
        d.row("nope")


def test_cache_is_bounded_and_least_recently_used_goes_first() -> None:
    d = Distances(roadmap(), cache_rows=2)
    ra = d.row("a")
    d.row("b")
    assert d.row("a") is ra  # cached
    d.row("c")  # evicts b, the least recently used
    assert d.row("a") is ra
    assert len(d._rows) == 2 and "b" not in d._rows
    with pytest.raises(ValueError, match="cache_rows"):
        Distances(roadmap(), cache_rows=0)
