"""The JSON codec under every wire message: typed structs (msgspec) decoded strictly, with
errors that name the field and the reason; payload size limits; the send-side check that
every number is finite.

A receiver calls :meth:`Codec.decode` (bytes) or :meth:`Codec.convert` (a ``dict`` already
parsed); both raise :class:`ValueError` whose message reads ``<field path>: <reason>``, e.g.
``status.battery: expected a finite number, got 'x'``, ``task.poses[0]: expected [x, y,
theta] of 3 finite numbers``, ``status.v: unsupported version 2 (expected 1)``,
``status.seq: missing``, ``payload: not JSON (...)``. A sender calls :func:`encode`: JSON
cannot carry NaN or infinity, so a non-finite number raises ``ValueError`` naming the field
instead of going out as ``null``. Types are the sender's contract (the structs are typed and
the tree is checked by mypy); every receiver validates everything again.
"""

from __future__ import annotations

import json
import math
import numbers
import re
import sys
from collections.abc import Callable, Mapping
from typing import Annotated, Final, Generic, TypeVar, Union

import msgspec
from msgspec import Meta, Struct

#: Version of every top-level message (field ``v``).
BUS_VERSION: Final = 1
#: Where a fleet's messages travel unless a config or a command says otherwise: the Zenoh
#: endpoint ``fleet run`` / ``fleet sim`` listen on and every other process connects to.
DEFAULT_ENDPOINT: Final = "tcp/127.0.0.1:7447"

#: Status, task and grant payloads larger than this are dropped unparsed.
MAX_PAYLOAD_BYTES: Final = 256 * 1024

#: Navigation protocol payloads (goal, cancel, state, clock) larger than this are dropped.
MAX_BRIDGE_PAYLOAD: Final = 1024 * 1024

_BIG = sys.float_info.max

#: A finite float (a JSON integer is accepted, a boolean never is).
Finite = Annotated[float, Meta(ge=-_BIG, le=_BIG)]

#: ``[x, y, theta]``: a pose in the ``map`` frame (m, m, rad).
Pose = tuple[Finite, Finite, Finite]

#: At most 10,000 poses.
Poses = Annotated[tuple[Pose, ...], Meta(max_length=10000)]

#: A short string (names, ids, modes).
Text = Annotated[str, Meta(max_length=256)]

#: A long string (error messages, behavior tree file names).
LongText = Annotated[str, Meta(max_length=4096)]

#: Largest count, epoch or sequence number on the wire: 2^53, the largest integer every JSON
#: reader keeps exact (a larger one, such as 2^62, is malformed).
MAX_SEQ: Final = 2**53

#: A non-negative integer, at most 2^53.
Count = Annotated[int, Meta(ge=0, le=MAX_SEQ)]

#: An epoch or a sequence number: an integer in [0, 2^53].
Seq = Annotated[int, Meta(ge=0, le=MAX_SEQ)]

#: What a robot name may look like: one Zenoh key chunk, e.g. ``robot3``.
ROBOT_NAME_PATTERN: Final = r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$"

#: A robot name (``robot3``): letters, digits, ``_ . -``, at most 128 characters.
RobotName = Annotated[str, Meta(pattern=ROBOT_NAME_PATTERN, max_length=128)]

Buffer = bytes | bytearray | memoryview | str

M = TypeVar("M", bound=Struct)


class _Unversioned(Struct, frozen=True, tag_field="v", tag=0):
    """Decoded in a union with a message so that ``v`` is required (msgspec treats the tag of
    a lone struct as optional); matching it means ``"v": 0``, an unsupported version."""


def _enc_hook(obj: object) -> object:
    # numpy scalars (float32, int64, bool_) reach the encoder from simulator state
    if isinstance(obj, numbers.Integral):
        return int(obj)
    if isinstance(obj, numbers.Real):
        return float(obj)
    item = getattr(obj, "item", None)
    if getattr(obj, "dtype", None) is not None and callable(item):
        return item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


_ENCODER = msgspec.json.Encoder(enc_hook=_enc_hook)


def encode(msg: Struct, what: str) -> bytes:
    """JSON of ``msg``. ValueError ``<what>.<field>: expected a finite number, got nan`` if a
    float is NaN or infinite, or if a field holds a value JSON cannot carry."""
    data = encode_unchecked(msg, what)
    if b"null" in data:  # msgspec writes NaN and infinity as null
        check_finite(msg, what)
    return data


def encode_unchecked(msg: Struct, what: str) -> bytes:
    """JSON of ``msg``, NaN and infinity written as ``null``: for a caller that checks its
    numbers itself. ValueError if a field holds a value JSON cannot carry."""
    try:
        return _ENCODER.encode(msg)
    except TypeError as e:
        raise ValueError(f"{what}: {e}") from None


def to_builtins(msg: Struct) -> dict[str, object]:
    """``msg`` as plain JSON-ready Python values (dicts, lists, str, int, float, bool, None)."""
    d = msgspec.to_builtins(msg, enc_hook=_enc_hook)
    assert isinstance(d, dict)
    return d


def check_finite(obj: object, path: str) -> None:
    """ValueError naming the first NaN or infinite float in ``obj`` (a struct, tuple, list or
    dict, walked recursively)."""
    if isinstance(obj, float):
        if not math.isfinite(obj):
            raise ValueError(f"{path}: expected a finite number, got {obj!r}")
    elif isinstance(obj, Struct):
        for name in obj.__struct_fields__:
            check_finite(getattr(obj, name), f"{path}.{name}")
    elif isinstance(obj, (tuple, list)):
        for i, v in enumerate(obj):
            check_finite(v, f"{path}[{i}]")
    elif isinstance(obj, dict):
        for k, v in obj.items():
            check_finite(v, f"{path}[{k!r}]")


class Codec(Generic[M]):
    """Strict decoding of message type ``cls``; errors name fields from ``what`` (``status``).

    ``versioned``: the message carries ``"v": 1`` (a tag of ``cls``), which is required.
    ``limit``: payloads larger than this many bytes are rejected unparsed. ``choices`` maps a
    field name to the values it may take, quoted in the error for an unknown one.
    """

    def __init__(
        self,
        cls: type[M],
        what: str,
        *,
        versioned: bool = True,
        limit: int = MAX_PAYLOAD_BYTES,
        choices: Mapping[str, tuple[str, ...]] | None = None,
    ) -> None:
        self.cls = cls
        self.what = what
        self.limit = limit
        self.choices = dict(choices or {})
        self._type: object = Union[cls, _Unversioned] if versioned else cls  # noqa: UP007 - runtime union
        self._decoder = msgspec.json.Decoder(self._type)

    def decode(self, data: Buffer, prefix: str | None = None) -> M:
        """Parse and validate one payload; ``prefix`` replaces ``what`` in error paths."""
        if isinstance(data, str):
            data = data.encode("utf-8")
        if len(data) > self.limit:
            raise ValueError(f"payload: {len(data)} bytes is larger than {self.limit}")
        try:
            msg = self._decoder.decode(data)
        except msgspec.ValidationError as e:
            raise ValueError(explain(e, prefix or self.what, lambda: _loose(data), self.choices)) from None
        except (msgspec.DecodeError, UnicodeDecodeError) as e:
            raise ValueError(_not_json(data, e)) from None
        return self._checked(msg, prefix)

    def convert(self, obj: object, prefix: str | None = None) -> M:
        """Validate ``obj`` (a ``dict`` as ``json.loads`` returns it) into the message."""
        try:
            msg = msgspec.convert(obj, self._type)
        except msgspec.ValidationError as e:
            raise ValueError(explain(e, prefix or self.what, lambda: obj, self.choices)) from None
        return self._checked(msg, prefix)

    def _checked(self, msg: object, prefix: str | None) -> M:
        if not isinstance(msg, self.cls):
            raise ValueError(f"{prefix or self.what}.v: unsupported version 0 (expected {BUS_VERSION})")
        return msg


def _not_json(data: bytes | bytearray | memoryview, err: Exception) -> str:
    try:
        bytes(data).decode("utf-8")
    except UnicodeDecodeError as e:
        return f"payload: not UTF-8 ({e.reason} at byte {e.start})"
    return f"payload: not JSON ({str(err)[:80]})"


def _loose(data: bytes | bytearray | memoryview) -> object:
    """The payload parsed without a schema, to quote an offending value (errors only)."""
    try:
        return json.loads(bytes(data))
    except (ValueError, RecursionError):
        return _NOTHING


_NOTHING = object()
_AT = re.compile(r"^(.*?)(?: - at `\$(.*)`)?$", re.S)
_STEP = re.compile(r"\.(\w+)|\[(\d+)\]|\[\.\.\.\]")


def _lookup(obj: object, where: str) -> object:
    """The value at msgspec path ``where`` (``.pose[1]``) in ``obj``, or ``_NOTHING``."""
    for m in _STEP.finditer(where):
        key, index = m.group(1), m.group(2)
        if key is not None and isinstance(obj, Mapping) and key in obj:
            obj = obj[key]
        elif index is not None and isinstance(obj, (list, tuple)) and int(index) < len(obj):
            obj = obj[int(index)]
        else:
            return _NOTHING
    return obj


def _quote(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def explain(
    err: msgspec.ValidationError,
    root: str,
    source: Callable[[], object],
    choices: Mapping[str, tuple[str, ...]] | None = None,
) -> str:
    """``<path>: <reason>`` for a msgspec validation error; ``source()`` returns the parsed
    payload (for quoting the offending value)."""
    m = _AT.match(str(err))
    text, where = (m.group(1), m.group(2) or "") if m else (str(err), "")
    path = root + where
    missing = re.match(r"Object missing required field `(.+)`", text)
    if missing:
        return f"{path}.{missing.group(1)}: missing"
    value = _lookup(source(), where)
    if where == ".v":
        return f"{path}: unsupported version {_quote(value)} (expected {BUS_VERSION})"
    reason = _reason(text, value, where.rsplit(".", 1)[-1], choices or {})
    return f"{path}: {reason}"


_REASONS: tuple[tuple[str, str], ...] = (
    (r"Expected `float`", "expected a finite number"),
    (r"Number out of range", "expected a finite number"),
    (r"Expected `int` >= (\S+)", "must be >= {0}"),
    (r"Expected `int` <= (\S+)", "must be <= {0}"),
    (r"Expected `int`", "expected an integer"),
    (r"Expected `bool`", "expected true or false"),
    (r"Expected `str` of length <= (\d+)", "string longer than {0} characters"),
    (r"Expected `str` matching regex", "not a valid robot name (use letters, digits, _ . -)"),
    (r"Expected `str`", "expected a string"),
    (r"Expected `array` of length 3", "expected [x, y, theta] of 3 finite numbers"),
    (r"Expected `array` of length <= (\d+)", "more than {0} items"),
    (r"Expected `array \| null`", "expected [x, y, theta] of 3 finite numbers or null"),
    (r"Expected `array`", "expected a list"),
    (r"Expected `object`", "expected a JSON object"),
    (r"Invalid (?:enum )?value", "unknown value"),
)


def _reason(text: str, value: object, field: str, choices: Mapping[str, tuple[str, ...]]) -> str:
    for pattern, template in _REASONS:
        m = re.match(pattern, text)
        if m is None:
            continue
        reason = template.format(*m.groups())
        if reason == "unknown value":
            shown = f" {_quote(value)}" if value is not _NOTHING else ""
            allowed = f" (expected one of {', '.join(choices[field])})" if field in choices else ""
            return f"{reason}{shown}{allowed}"
        break
    else:
        reason = text[:1].lower() + text[1:]
    if value is not _NOTHING:
        return f"{reason}, got {_quote(value)}"
    got = re.search(r"got `(\w+)`", text)
    return f"{reason}, got {got.group(1)}" if got else reason
