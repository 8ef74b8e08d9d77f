"""Field types of the config schema (:mod:`fleet.config.schema`).

Each type is a plain Python type with one piece of metadata that checks a YAML value and, when
it is wrong, says so in the words of ``docs/config.md`` (``must be a positive number, got
-1.0``). The same metadata gives the JSON Schema its bounds and patterns, so the published
schema and the checks cannot disagree. A problem is a :func:`problem` error: pydantic collects
it with the path of the value, and :func:`fleet.config.schema.validate_document` turns the
first one into a :class:`~fleet.errors.ConfigError` ``<file>: <field>: <reason>``.

To tighten a field, change its metadata: ``Annotated[float, Bounds(gt=0, le=20)]`` checks,
documents and publishes the new range at once.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TypeVar

from pydantic import GetCoreSchemaHandler, GetJsonSchemaHandler
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import PydanticCustomError, core_schema

#: A name of a robot, charger, station, route or task.
NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]*$"
#: A robot's ROS namespace.
NAMESPACE_PATTERN = r"^/[A-Za-z][A-Za-z0-9_]*$"
#: A Zenoh endpoint ``<protocol>/<address>``.
ENDPOINT_PATTERN = r"^[a-z][a-z0-9-]*/\S+$"

#: Key chunks the status bus uses itself (``fleet/sim/clock``, ``fleet/control/state``,
#: ``fleet/service/...``; :data:`fleet.bus.keys.RESERVED_CHUNKS`): no robot may be named so.
RESERVED_NAMES = frozenset({"sim", "control", "service"})

_T = TypeVar("_T")

#: The pydantic error type of every problem raised here.
PROBLEM = "fleet_config"


def problem(reason: str, *at: str | int) -> PydanticCustomError:
    """A validation error with ``reason`` as its message. ``at`` continues the path of the
    value being checked (e.g. the key of a mapping, or ``(4, "name")`` inside a list)."""
    return PydanticCustomError(PROBLEM, "{reason}", {"reason": reason, "at": at})


def tname(v: object) -> str:
    """The type of ``v`` as a user reads it (``nothing`` for a missing YAML value)."""
    return "nothing" if v is None else type(v).__name__


def suggest(word: str, options: Iterable[object], otherwise: str = "") -> str:
    """`` (did you mean 'x'?)`` for the option closest to ``word``, or ``otherwise``."""
    match = difflib.get_close_matches(word, [str(o) for o in options], n=1)
    return f" (did you mean {match[0]!r}?)" if match else otherwise


def is_number(v: object) -> bool:
    """True for a finite int or float that is not a bool."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class Bounds:
    """A finite number (an int where the field is ``int``), never a bool, within the bounds.

    ``what`` names the expected value in the reason (``must be <what>, got <value>``); by
    default it is derived from the bounds (``a positive number``, ``a number >= 0``, ``a
    number in [0, 10]``).
    """

    what: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None

    def describe(self, integer: bool) -> str:
        """What the reason says the value must be."""
        if self.what:
            return self.what
        kind = "an integer" if integer else "a number"
        low = (
            ("(", ">", self.gt)
            if self.gt is not None
            else ("[", ">=", self.ge)
            if self.ge is not None
            else None
        )
        high = (
            (")", "<", self.lt)
            if self.lt is not None
            else ("]", "<=", self.le)
            if self.le is not None
            else None
        )
        if low and high:
            if low[1] == ">" and low[2] == 0:
                positive = "a positive integer" if integer else "a positive number"
                return f"{positive} {'up to' if high[1] == '<=' else 'below'} {high[2]:g}"
            return f"{kind} in {low[0]}{low[2]:g}, {high[2]:g}{high[0]}"
        if low:
            if low[1] == ">" and low[2] == 0:
                return "a positive integer" if integer else "a positive number"
            return f"{kind} {low[1]} {low[2]:g}"
        if high:
            return f"{kind} {high[1]} {high[2]:g}"
        return kind

    def within(self, x: float) -> bool:
        return (
            (self.gt is None or x > self.gt)
            and (self.ge is None or x >= self.ge)
            and (self.lt is None or x < self.lt)
            and (self.le is None or x <= self.le)
        )

    def __get_pydantic_core_schema__(
        self, source: object, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        integer = source is int
        what = self.describe(integer)

        def check(v: object) -> float | int:
            if (
                isinstance(v, bool)
                or not isinstance(v, int | float)
                or not math.isfinite(v)
                or (integer and not isinstance(v, int))
                or not self.within(v)
            ):
                raise problem(f"must be {what}, got {v!r}")
            return v if integer else float(v)

        inner: core_schema.CoreSchema
        if integer:
            inner = core_schema.int_schema(
                gt=_int(self.gt), ge=_int(self.ge), lt=_int(self.lt), le=_int(self.le), strict=True
            )
        else:
            inner = core_schema.float_schema(
                gt=self.gt, ge=self.ge, lt=self.lt, le=self.le, allow_inf_nan=False
            )
        return core_schema.no_info_before_validator_function(check, inner)


def _int(x: float | None) -> int | None:
    return None if x is None else int(x)


@dataclass(frozen=True)
class Flag:
    """``true`` or ``false`` (not 0 / 1, not ``"yes"``)."""

    def __get_pydantic_core_schema__(
        self, source: object, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        def check(v: object) -> bool:
            if not isinstance(v, bool):
                raise problem(f"must be true or false, got {v!r}")
            return v

        return core_schema.no_info_before_validator_function(check, core_schema.bool_schema(strict=True))


@dataclass(frozen=True)
class Text:
    """A non-empty string, optionally matching ``pattern``.

    Reasons: ``must be <what>, got <value>`` for a value that is not a non-empty string,
    ``must <expect>, got <value>`` for one that does not match ``pattern``.
    """

    pattern: str | None = None
    expect: str = ""
    what: str = "a non-empty string"

    def __get_pydantic_core_schema__(
        self, source: object, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        compiled = re.compile(self.pattern) if self.pattern else None

        def check(v: object) -> str:
            if not isinstance(v, str) or not v:
                raise problem(f"must be {self.what}, got {v!r}")
            if compiled is not None and not compiled.fullmatch(v):
                raise problem(f"must {self.expect}, got {v!r}")
            return v

        inner = core_schema.str_schema(min_length=1, pattern=self.pattern)
        return core_schema.no_info_before_validator_function(check, inner)


def numbers(v: object, n: int) -> tuple[float, ...] | None:
    """``v`` as a tuple of ``n`` floats if it is a list of ``n`` finite numbers, else ``None``."""
    if isinstance(v, list | tuple) and len(v) == n and all(is_number(x) for x in v):
        return tuple(float(x) for x in v)
    return None


@dataclass(frozen=True)
class Numbers:
    """A list of exactly ``n`` finite numbers (a pose ``[x, y, theta]``, a point ``[x, y]``).

    A string is also accepted when ``names`` is set: a reference by name (a roadmap node, a
    station), resolved after the schema (:mod:`fleet.config.checks`). ``expect`` is what the
    reason says the value must be.
    """

    n: int
    expect: str
    names: bool = False

    def __get_pydantic_core_schema__(
        self, source: object, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        def check(v: object) -> str | tuple[float, ...]:
            if self.names and isinstance(v, str):
                return v
            xs = numbers(v, self.n)
            if xs is None:
                raise problem(f"must be {self.expect}, got {v!r}")
            return xs

        tup = core_schema.tuple_schema([core_schema.float_schema(allow_inf_nan=False)] * self.n)
        inner = core_schema.union_schema([core_schema.str_schema(), tup]) if self.names else tup
        return core_schema.no_info_before_validator_function(check, inner)

    def __get_pydantic_json_schema__(
        self, schema: core_schema.CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        return {**handler(schema), "description": self.expect}


@dataclass(frozen=True)
class Items:
    """A list (a missing or empty YAML value is an empty list).

    ``min_items``: fewer entries is an error whose reason is ``too_few`` (``{n}`` is the count).
    ``unique``: entries with the same ``name`` are an error at ``[i].name`` whose reason is
    ``unique`` (``{name}`` is the repeated name, quoted).
    """

    min_items: int = 0
    too_few: str = ""
    unique: str = ""

    def __get_pydantic_core_schema__(
        self, source: object, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        def check(v: object) -> list[object]:
            if v is None:
                v = []
            if not isinstance(v, list):
                raise problem(f"must be a list, got {tname(v)}")
            if len(v) < self.min_items:
                raise problem(self.too_few.format(n=len(v)))
            return v

        inner = handler(source)
        if self.min_items and inner["type"] == "list":
            inner = {**inner, "min_length": self.min_items}
        schema = core_schema.no_info_before_validator_function(check, inner)
        if self.unique:
            return core_schema.no_info_after_validator_function(self._check_unique, schema)
        return schema

    def _check_unique(self, items: Sequence[object]) -> Sequence[object]:
        unique_by(items, lambda item: str(getattr(item, "name", "")), "name", self.unique)
        return items


def unique_by(items: Sequence[_T], key: Callable[[_T], str], field: str, reason: str) -> None:
    """Raise a :func:`problem` at ``[i].<field>`` for the first entry whose ``key`` repeats an
    earlier one; ``reason`` may use ``{name}`` (the repeated key, quoted)."""
    seen: set[str] = set()
    for i, item in enumerate(items):
        k = key(item)
        if k in seen:
            raise problem(reason.format(name=repr(k)), i, field)
        seen.add(k)


def not_reserved(v: str) -> str:
    """``v`` (a robot name or namespace) unless its last token is a key chunk of the bus."""
    if v.strip("/") in RESERVED_NAMES:
        raise problem(
            f"{v!r} is a key the fleet's bus uses itself ({', '.join(sorted(RESERVED_NAMES))}); "
            "choose another name"
        )
    return v


def valid_port(endpoint: str) -> str:
    """``endpoint`` unless it ends in ``:<port>`` with a port outside 1..65535."""
    address = endpoint.split("/", 1)[1].split("#", 1)[0]
    head, sep, port = address.rpartition(":")
    if sep and head and port.isdigit() and not 1 <= int(port) <= 65535:
        raise problem(f"port {port} is not a TCP/UDP port (1..65535), got {endpoint!r}")
    if sep and head and not port.isdigit() and not head.startswith("["):
        raise problem(f"port {port!r} is not a number, got {endpoint!r}")
    return endpoint
