"""Status batches: one put carrying many robots' records, decoded transparently by every
status subscriber; malformed batches and malformed records inside a batch are counted and
dropped with the field named. Real Zenoh sessions on loopback."""

from __future__ import annotations

import gc
import math
import threading

import msgspec
import pytest
import zenoh
from bus_peer import record, settle, wait_until

from fleet.bus.keys import status_batch_key
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord
from fleet.messages.status_batch import MAX_BATCH_RECORDS, decode_batch, encode_batch


def test_batch_round_trip_keeps_every_field_and_order() -> None:
    recs = [record(f"robot{i}", i, lost=i % 3 == 0) for i in range(1, 8)]
    got = decode_batch(encode_batch("proc-1", recs))
    assert got.source == "proc-1" and got.errors == [] and got.records == recs


def test_bad_records_inside_a_batch_are_named_and_the_rest_kept() -> None:
    good = [msgspec.to_builtins(record(f"robot{i}", i)) for i in range(3)]
    bad_battery = {**good[1], "battery": "full"}
    no_seq = {k: v for k, v in good[2].items() if k != "seq"}
    data = msgspec.msgpack.encode({"v": 1, "source": "p", "records": [good[0], bad_battery, no_seq, 7]})
    got = decode_batch(data)
    assert [r.robot for r in got.records] == ["robot0"]
    assert got.errors[0] == "status[1].battery: expected a finite number, got 'full'"
    assert got.errors[1] == "status[2].seq: missing"
    assert got.errors[2] == "status[3]: expected a MessagePack map, got 7"


@pytest.mark.parametrize(
    ("payload", "needle"),
    [
        (b"\xc1garbage", "payload: not a MessagePack status batch"),
        (b'{"v": 1}', "batch: expected a MessagePack map, got int"),  # JSON is not a batch
        (msgspec.msgpack.encode({"v": 2, "source": "p", "records": []}), "batch.v: unsupported version 2"),
        (msgspec.msgpack.encode({"v": 1, "records": []}), "batch.source: missing"),
        (msgspec.msgpack.encode({"v": 1, "source": "p", "records": 3}), "batch.records: expected a list"),
    ],
)
def test_a_message_that_is_not_a_batch_is_one_error(payload: bytes, needle: str) -> None:
    with pytest.raises(ValueError) as err:
        decode_batch(payload)
    assert str(err.value).startswith(needle), str(err.value)


def test_publishing_a_non_finite_number_names_the_field_at_once(zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as session:
        bus = StatusBus(session, batch_source="p")
        try:
            bad = msgspec.structs.replace(record("robot1", 1), battery=math.nan)
            with pytest.raises(ValueError, match=r"status\.battery: expected a finite number"):
                bus.publish_status(bad)
            assert bus.flush_statuses() == 0  # nothing was queued
        finally:
            bus.shutdown()


#: Hang guard (wall s) of one record's or one round's delivery on a loaded 2-core machine.
DELIVERY_S = 30.0


def _views(n: int, batch: bool, endpoint: str) -> tuple[dict[str, StatusRecord], list[StatusRecord], int]:
    """Publish rounds of ``n`` robots from a client (batched or one put per record) to a
    router-side subscriber; returns its latest table, every record it received, and puts sent."""
    with open_session(endpoint, "router") as router, open_session(endpoint, "client") as client:
        sub = StatusBus(router)
        # no batch delay: batches of 500 whatever the machine's speed (the delay: below)
        pub = StatusBus(client, batch_source="loadtest-w1" if batch else None, batch_delay_s=None)
        try:
            seen: list[StatusRecord] = []
            arrived = threading.Condition()

            def take(rec: StatusRecord) -> None:
                with arrived:
                    seen.append(rec)
                    arrived.notify_all()

            sub.subscribe_statuses(take)

            def warm() -> None:
                pub.publish_status(record("warmup", 0))
                pub.flush_statuses()

            settle(warm, lambda: bool(seen), 30, "the subscription")
            seen.clear()
            pub.status_puts = 0
            for k in range(1, 4):
                for i in range(n):
                    pub.publish_status(record(f"robot{i}", k))
                    sent = (k - 1) * n + i + 1
                    if not batch:
                        # one put per record is sent with congestion control "drop" (a status
                        # is superseded by the next): a burst from one client overflows the
                        # transmit queue while a loaded machine starves the receiver (a pace
                        # of 100 in flight once lost 56 in CI), so each record is awaited
                        with arrived:
                            got = arrived.wait_for(lambda s=sent: len(seen) >= s, DELIVERY_S)
                        assert got, f"{sent} records (got {len(seen)})"
                pub.flush_statuses()
            wait_until(lambda: len(seen) >= 3 * n, DELIVERY_S, f"{3 * n} records (got {len(seen)})")
            latest = {k: v for k, v in sub.latest().items() if k != "warmup"}
            assert sub.malformed == 0, sub.last_malformed
            return latest, [r for r in seen if r.robot != "warmup"], pub.status_puts
        finally:
            pub.shutdown()
            sub.shutdown()


def test_batched_and_unbatched_give_subscribers_the_same_view(zenoh_endpoint: str) -> None:
    """1200 robots, 3 rounds: the same latest table and the same records in the same order
    per robot; batching sends 3 puts per round (500 + 500 + 200 records) instead of 1200."""
    n = 1200
    latest_b, seen_b, puts_b = _views(n, True, zenoh_endpoint)
    latest_u, seen_u, puts_u = _views(n, False, zenoh_endpoint)
    assert latest_b == latest_u and len(latest_b) == n
    assert all(r.seq == 3 for r in latest_b.values())

    def per_robot(seen: list[StatusRecord]) -> dict[str, list[int]]:
        out: dict[str, list[int]] = {}
        for r in seen:
            out.setdefault(r.robot, []).append(r.seq)
        return out

    assert per_robot(seen_b) == per_robot(seen_u) == {f"robot{i}": [1, 2, 3] for i in range(n)}
    assert puts_u == 3 * n and puts_b == 3 * math.ceil(n / MAX_BATCH_RECORDS)


def test_malformed_batches_on_the_bus_are_counted_and_the_good_records_kept(zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as router, open_session(zenoh_endpoint, "client") as client:
        sub = StatusBus(router)
        try:
            seen: list[StatusRecord] = []
            arrived = threading.Condition()

            def take(rec: StatusRecord) -> None:
                with arrived:
                    seen.append(rec)
                    arrived.notify_all()

            sub.subscribe_statuses(take)
            key = status_batch_key("w1")
            block = zenoh.CongestionControl.BLOCK
            settle(
                lambda: client.put(key, encode_batch("w1", [record("a", 0)])),
                lambda: bool(seen),
                30,
                "a batch",
            )
            base = sub.malformed
            client.put(key, b"\xc1 not msgpack", congestion_control=block)
            good = msgspec.to_builtins(record("b", 5))
            mixed = {"v": 1, "source": "w1", "records": [good, {**good, "robot": "c", "laps": -1}]}
            client.put(key, msgspec.msgpack.encode(mixed), congestion_control=block)
            wait_until(lambda: sub.malformed == base + 2 and "b" in sub.latest(), 30, "2 malformed, robot b")
            assert sub.last_malformed == "fleet/batch/w1/status: status[1].laps: must be >= 0, got -1"
            assert "c" not in sub.latest() and sub.latest()["b"].seq == 5
        finally:
            sub.shutdown()


def test_a_batch_leaves_once_its_oldest_record_waited_the_delay(zenoh_endpoint: str) -> None:
    """``batch_delay_s``: with 0 every queued record is already old enough, so each goes out
    with the next publish; with an hour nothing leaves before the flush (or a full batch).
    No clock is read by the test: the two ends of the range decide alone."""
    with open_session(zenoh_endpoint, "router") as session:
        eager = StatusBus(session, batch_source="p0", batch_delay_s=0.0)
        patient = StatusBus(session, batch_source="p1", batch_delay_s=3600.0)
        try:
            for bus in (eager, patient):
                for i in range(3):
                    bus.publish_status(record(f"robot{i}", 1))
            assert eager.status_puts == 3 and eager.flush_statuses() == 0
            assert patient.status_puts == 0 and patient.flush_statuses() == 3
            assert patient.status_puts == 1
            for i in range(MAX_BATCH_RECORDS):  # a full batch does not wait for the hour
                patient.publish_status(record(f"robot{i}", 2))
            assert patient.status_puts == 2 and patient.flush_statuses() == 0
        finally:
            eager.close()
            patient.shutdown()


def test_status_records_are_not_tracked_by_the_garbage_collector() -> None:
    """A subscriber keeps thousands of records (latest table, coordinator inbox); untracked,
    they cost the collector nothing (docs/performance.md, "Target 4")."""
    recs = decode_batch(encode_batch("p", [record(f"robot{i}", i) for i in range(3)])).records
    assert recs and not any(gc.is_tracked(r) for r in recs)
    assert not gc.is_tracked(StatusRecord.from_json(recs[0].to_json()))
