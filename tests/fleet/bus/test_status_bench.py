"""The status-bus bench's accounting (``bench/status_bus.py``, issue 12 target 4): what it calls
lost, late and doubled is what happened, and at small N through a real router every robot's
records arrive, in order. No timing is asserted: the figures live in docs/performance.md."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parents[3] / "bench" / "status_bus.py"


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("status_bus_bench", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up by name
    spec.loader.exec_module(mod)
    return mod


def test_tally_counts_gaps_late_and_doubled_records_per_robot(bench: ModuleType) -> None:
    t = bench.SeqTally()
    for robot, seq in [("a", 1), ("a", 2), ("b", 1), ("a", 5), ("a", 3), ("a", 3), ("b", 2), ("a", 6)]:
        t.take(robot, seq, 0.001 * seq)
    assert t.received == 8
    assert t.late == 1  # a3 filled its gap
    assert t.duplicate == 1  # the second a3
    assert t.missing == {"a": {4}}
    # a sent 7 (4 and 7 missing), b sent 3 (3 missing), c sent 2 (none arrived)
    assert t.gaps() == 1
    assert t.lost({"a": 7, "b": 3, "c": 2}) == 2 + 1 + 2
    assert not t.in_order()
    clean = bench.SeqTally()
    for seq in (1, 2, 3):
        clean.take("r", seq, 0.0)
    assert clean.lost({"r": 3}) == 0 and clean.in_order()


def test_percentile_is_nearest_rank_in_ms(bench: ModuleType) -> None:
    vals = [i / 1000 for i in range(1, 101)]  # 1..100 ms
    assert bench.percentile_ms(vals, 0.5) == pytest.approx(51.0)
    assert bench.percentile_ms(vals, 0.99) == pytest.approx(100.0)
    assert bench.percentile_ms(vals, 1.0) == pytest.approx(100.0)


def test_fifty_robots_over_two_workers_arrive_complete_and_in_order(bench: ModuleType) -> None:
    tally = bench.SeqTally()
    r = bench.run(50, 2, 10.0, 1.0, spread=0.8, malformed=3, tally=tally)
    rounds = 10
    assert r.sent == 50 * rounds
    assert r.received == r.sent and r.lost == 0
    assert r.late == 0 and r.duplicate == 0
    assert tally.last == {f"robot{i}": rounds for i in range(1, 51)}  # every robot, to the last record
    assert tally.missing == {}
    assert r.malformed == r.malformed_sent == 3  # bad batches counted and dropped
    assert len(tally.latencies) == r.received
    assert r.p50_ms <= r.p95_ms <= r.p99_ms <= r.max_ms
    assert r.ok
