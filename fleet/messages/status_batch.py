"""Status batches: many robots' status records in one message (``fleet/batch/<source>/status``).

A process that runs many agents (``fleet loadtest``, a ``fleet run`` or ``fleet agent`` with
several robots) sends its robots' records as one batch per tick instead of one message per
robot: one Zenoh put carries up to :data:`MAX_BATCH_RECORDS` records. The batch is
MessagePack (``msgspec.msgpack``), not JSON: measured on 1000 typical records
(``bench/bench_messages.py``-style, one run) encoding the batch took 0.14 µs per record in
MessagePack against 1.0 µs in JSON, decoding and validating 2.8 against 3.1 µs, and the batch
is 13 % smaller. A single robot's ``fleet/<robot>/status`` stays JSON (readable, documented in
``docs/status_bus.md``).

Wire form: a MessagePack map ``{"v": 1, "source": <text>, "records": [<status record>, ...]}``
where each record is the MessagePack form of :class:`~fleet.messages.StatusRecord` (the same
fields and ``"v": 1`` as its JSON). Receivers validate every record on its own: a malformed
record is reported by index and field (``status[3].battery: expected a finite number, got
'x'``) and dropped, while the batch's good records are kept; a batch that is not a batch at all
(not MessagePack, wrong version, too large) is one malformed message.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Final, Union

import msgspec
from msgspec import Meta, Struct

from fleet.messages.codec import (
    _NOTHING,
    BUS_VERSION,
    MAX_BRIDGE_PAYLOAD,
    Buffer,
    Text,
    check_finite,
    explain,
)
from fleet.messages.records import STATUS_CODEC, StatusRecord

#: A sender splits its records into batches of at most this many (one put each).
MAX_BATCH_RECORDS: Final = 500

#: Batch payloads larger than this are dropped unparsed (500 records are about 115 KB).
MAX_BATCH_BYTES: Final = MAX_BRIDGE_PAYLOAD


class _BatchOut(Struct, frozen=True, tag_field="v", tag=BUS_VERSION):
    source: str
    records: Sequence[StatusRecord]


class _BatchIn(Struct, frozen=True, tag_field="v", tag=BUS_VERSION):
    source: Text
    records: Annotated[list[msgspec.Raw], Meta(max_length=MAX_BATCH_RECORDS * 2)]


class _BatchWhole(Struct, frozen=True, tag_field="v", tag=BUS_VERSION):
    source: Text
    records: Annotated[list[StatusRecord], Meta(max_length=MAX_BATCH_RECORDS * 2)]


class _Unversioned(Struct, frozen=True, tag_field="v", tag=0):
    """Matched when ``v`` is 0 (an unsupported version); makes ``v`` required."""


_ENCODER: Final = msgspec.msgpack.Encoder()
_BATCH_DECODER: Final = msgspec.msgpack.Decoder(Union[_BatchIn, _Unversioned])  # noqa: UP007 - runtime union
_WHOLE_DECODER: Final = msgspec.msgpack.Decoder(_BatchWhole)
_RECORD_DECODER: Final = msgspec.msgpack.Decoder(Union[StatusRecord, _Unversioned])  # noqa: UP007


def _finite(rec: StatusRecord) -> bool:
    """Every float of ``rec`` is finite (one sum: NaN and infinity propagate)."""
    p = rec.pose
    try:
        total = rec.t + rec.battery + rec.progress + rec.distance_m
        if p is not None:
            total += p[0] + p[1] + p[2]
        return math.isfinite(total)
    except TypeError:
        return False


def check_status(rec: StatusRecord) -> StatusRecord:
    """``rec`` if it can be sent; ValueError naming the field for a NaN or infinite number
    (the same contract as :meth:`StatusRecord.to_json`)."""
    if not _finite(rec):
        check_finite(rec, "status")
        STATUS_CODEC.convert(msgspec.to_builtins(rec))  # a wrongly typed field: named here
    return rec


def encode_batch(source: str, records: Sequence[StatusRecord]) -> bytes:
    """One batch of ``records`` (at most :data:`MAX_BATCH_RECORDS`, already checked with
    :func:`check_status`) from ``source`` (the sending process's name), as MessagePack."""
    return _ENCODER.encode(_BatchOut(source, records))


@dataclass(frozen=True)
class DecodedBatch:
    """What :func:`decode_batch` found: the sender, its valid records (in order) and one
    ``status[<index>].<field>: <reason>`` line per record dropped."""

    source: str
    records: list[StatusRecord]
    errors: list[str]


def decode_batch(data: Buffer) -> DecodedBatch:
    """Parse a batch; ValueError (``batch...: <reason>``) if the message as a whole is not a
    valid batch. Bad records inside a valid batch are returned in ``errors``, not raised."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    if len(data) > MAX_BATCH_BYTES:
        raise ValueError(f"payload: {len(data)} bytes is larger than {MAX_BATCH_BYTES}")
    try:  # the common case, every record valid: one decoder pass over the whole batch
        whole = _WHOLE_DECODER.decode(data)
        return DecodedBatch(whole.source, whole.records, [])
    except (msgspec.ValidationError, msgspec.DecodeError):
        pass  # the batch itself, then its records one by one, to say what is wrong
    try:
        batch = _BATCH_DECODER.decode(data)
    except msgspec.ValidationError as e:
        raise ValueError(_map(explain(e, "batch", lambda: _loose(data)))) from None
    except msgspec.DecodeError as e:
        raise ValueError(f"payload: not a MessagePack status batch ({str(e)[:80]})") from None
    if not isinstance(batch, _BatchIn):
        raise ValueError(f"batch.v: unsupported version 0 (expected {BUS_VERSION})")
    good: list[StatusRecord] = []
    errors: list[str] = []
    for i, raw in enumerate(batch.records):
        what = f"status[{i}]"
        try:
            rec = _RECORD_DECODER.decode(raw)
        except msgspec.ValidationError as e:
            errors.append(_explain_record(e, what, raw))
            continue
        except msgspec.DecodeError as e:
            errors.append(f"{what}: not MessagePack ({str(e)[:60]})")
            continue
        if not isinstance(rec, StatusRecord):
            errors.append(f"{what}.v: unsupported version 0 (expected {BUS_VERSION})")
            continue
        good.append(rec)
    return DecodedBatch(batch.source, good, errors)


def _explain_record(err: msgspec.ValidationError, what: str, raw: msgspec.Raw) -> str:
    return _map(explain(err, what, lambda: _loose(raw), STATUS_CODEC.choices))


def _map(reason: str) -> str:
    """The codec's reasons speak of JSON; a batch is MessagePack."""
    return reason.replace("a JSON object", "a MessagePack map")


def _loose(data: Buffer | msgspec.Raw) -> object:
    """The payload parsed without a schema, to quote an offending value (errors only)."""
    try:
        return msgspec.msgpack.decode(data.encode() if isinstance(data, str) else data)
    except (msgspec.DecodeError, ValueError, RecursionError):
        return _NOTHING
