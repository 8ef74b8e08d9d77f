"""What a user submits: one JSON object per task, ``kind`` and its arguments (pydantic, so
the HTTP API's OpenAPI schema documents it), and the validation every face shares.

Targets (``target``, ``pickup``, ``dropoff``, ``waypoints``) are a station name, a roadmap
node name, ``[x, y]`` / ``[x, y, theta]`` or ``{"x": .., "y": .., "theta": ..}`` (``map``
frame, m, rad). Every kind takes ``priority`` (higher first, -1000..1000, default 0),
``robot`` (the one robot allowed to take it) and ``name`` (a label). See ``docs/service.md``.

:func:`parse_spec` turns a parsed JSON object into a :data:`TaskSpec`, raising
:class:`~fleet.errors.InvalidTask` that names the field (``waypoints[2].action: ...``);
:mod:`fleet.service.factory` checks it against the fleet (stations, nodes, reachable poses).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Final, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    TypeAdapter,
    ValidationError,
    WithJsonSchema,
    model_validator,
)

from fleet.errors import InvalidTask

#: The kinds a user may submit.
KINDS: Final = ("patrol", "pick", "go_to", "inspection", "charge", "park")
#: Inspection actions (``capture:<name>`` names a capture).
INSPECTION_ACTIONS: Final = ("wait", "spin", "capture")
#: At most this many waypoints in one task.
MAX_WAYPOINTS: Final = 1000


@dataclass(frozen=True)
class PoseRef:
    """An explicit target pose (``map`` frame); ``theta`` ``None``: any heading."""

    x: float
    y: float
    theta: float | None = None


def _finite(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ValueError(f"{what}: expected a finite number, got {v!r}")
    return float(v)


def parse_target(v: object) -> str | PoseRef:
    """A station or node name, or a pose (see the module docstring); ValueError otherwise."""
    if isinstance(v, str):
        if not 0 < len(v) <= 128:
            raise ValueError("expected a station or roadmap node name of 1 to 128 characters")
        return v
    if isinstance(v, (list, tuple)):
        if len(v) not in (2, 3):
            raise ValueError(f"expected [x, y] or [x, y, theta], got {len(v)} numbers")
        xs = [_finite(c, name) for c, name in zip(v, ("x", "y", "theta"), strict=False)]
        return PoseRef(xs[0], xs[1], xs[2] if len(xs) == 3 else None)
    if isinstance(v, dict):
        extra = set(v) - {"x", "y", "theta"}
        if extra or "x" not in v or "y" not in v:
            raise ValueError('expected {"x": .., "y": .., "theta": ..} (theta optional)')
        theta = v.get("theta")
        return PoseRef(
            _finite(v["x"], "x"), _finite(v["y"], "y"), None if theta is None else _finite(theta, "theta")
        )
    raise ValueError(f"expected a station or node name or a pose, got {type(v).__name__}")


def _dump_target(v: str | PoseRef) -> object:
    if isinstance(v, str):
        return v
    return [v.x, v.y] if v.theta is None else [v.x, v.y, v.theta]


_TARGET_SCHEMA: dict[str, Any] = {
    "description": "a station name, a roadmap node name, [x, y], [x, y, theta] or {x, y, theta} (map frame)",
    "anyOf": [
        {"type": "string", "maxLength": 128},
        {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 3},
        {
            "type": "object",
            "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "theta": {"type": "number"}},
            "required": ["x", "y"],
        },
    ],
}

#: A target (station, node or pose).
Target = Annotated[
    str | PoseRef,
    PlainValidator(parse_target),
    PlainSerializer(_dump_target),
    WithJsonSchema(_TARGET_SCHEMA),
]


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, str_max_length=256)

    priority: int = Field(0, ge=-1000, le=1000, description="higher is matched first")
    robot: str | None = Field(None, max_length=128, description="the one robot allowed to take the task")
    name: str | None = Field(None, max_length=128, description="a label for people")


class PatrolSpec(_Spec):
    """Drive a loop: a config ``route`` by name, or ``waypoints``; ``laps`` times (at least
    1) or, without ``laps``, until canceled."""

    kind: Literal["patrol"]
    route: str | None = Field(None, max_length=128, description="a route of the fleet config")
    waypoints: list[Target] | None = Field(None, min_length=2, max_length=MAX_WAYPOINTS)
    laps: int | None = Field(None, ge=1, le=1_000_000, description="laps to drive (default: until canceled)")

    @model_validator(mode="after")
    def _one_way(self) -> PatrolSpec:
        if (self.route is None) == (self.waypoints is None):
            raise ValueError("route: give exactly one of route (a config route) and waypoints")
        return self


class PickSpec(_Spec):
    """Drive to ``pickup``, stand ``dwell_s`` s, drive to ``dropoff``."""

    kind: Literal["pick"]
    pickup: Target
    dropoff: Target
    dwell_s: float = Field(5.0, ge=0.0, le=3600.0, description="seconds at the pickup")


class GoToSpec(_Spec):
    """Drive to ``target``."""

    kind: Literal["go_to"]
    target: Target


class InspectionStop(BaseModel):
    """One inspection waypoint with its own action (else the task's)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    target: Target
    action: str | None = Field(None, description="wait, spin, capture or capture:<name>")
    duration_s: float | None = Field(None, ge=0.0, le=3600.0)
    yaw: float | None = Field(None, ge=-100.0, le=100.0, description="spin angle (rad, signed)")
    capture: str | None = Field(None, max_length=128, description="the capture's name")


class InspectionSpec(_Spec):
    """Drive to each waypoint and act there: ``wait`` ``duration_s``, ``spin`` by ``yaw``, or
    ``capture`` (named ``capture:<name>``, else after the waypoint)."""

    kind: Literal["inspection"]
    waypoints: list[Target | InspectionStop] = Field(min_length=1, max_length=MAX_WAYPOINTS)
    action: str = Field("wait", description="wait, spin, capture or capture:<name>")
    duration_s: float = Field(2.0, ge=0.0, le=3600.0, description="seconds of a wait")
    yaw: float = Field(2 * math.pi, ge=-100.0, le=100.0, description="spin angle (rad, signed)")

    @model_validator(mode="after")
    def _actions(self) -> InspectionSpec:
        check_action(self.action, "action")
        for i, w in enumerate(self.waypoints):
            if isinstance(w, InspectionStop) and w.action is not None:
                check_action(w.action, f"waypoints[{i}].action")
        return self


class ChargeSpec(_Spec):
    """Go to the robot's charger now and charge to the resume level."""

    kind: Literal["charge"]


class ParkSpec(_Spec):
    """Drive to a parking spot (``target``, default: a free one of the config)."""

    kind: Literal["park"]
    target: Target | None = None


def check_action(action: str, where: str) -> None:
    """ValueError unless ``action`` is one of :data:`INSPECTION_ACTIONS` (or ``capture:<name>``)."""
    base, _, label = action.partition(":")
    if base not in INSPECTION_ACTIONS or (label and base != "capture"):
        raise ValueError(f"{where}: {action!r} is not one of wait, spin, capture, capture:<name>")


#: A task as submitted (one of the kinds, by ``kind``).
TaskSpec = Annotated[
    PatrolSpec | PickSpec | GoToSpec | InspectionSpec | ChargeSpec | ParkSpec,
    Field(discriminator="kind"),
]
TASK_SPEC: Final[TypeAdapter[TaskSpec]] = TypeAdapter(TaskSpec)


def field_path(loc: tuple[int | str, ...], kind_tag: bool = True) -> str:
    """``waypoints[2].action`` for pydantic's ``('inspection', 'waypoints', 2, 'action')``
    (the union's tag is dropped)."""
    parts = list(loc)
    if kind_tag and parts and parts[0] in KINDS:
        parts = parts[1:]
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        elif p in ("InspectionStop", "function-plain[parse_target()]", "str"):
            continue
        else:
            out += f".{p}" if out else str(p)
    return out


def explain(err: ValidationError) -> InvalidTask:
    """The first error of ``err`` as :class:`InvalidTask` (field and reason)."""
    return explain_errors(list(err.errors(include_url=False)))


def explain_errors(errors: Sequence[Mapping[str, Any]]) -> InvalidTask:
    """The first of pydantic's ``errors()`` as :class:`InvalidTask` (a leading ``body``
    location, as FastAPI reports them, is dropped)."""
    if not errors:
        return InvalidTask("", "invalid request")
    first = errors[0]
    kind = first.get("type", "")
    loc = tuple(first.get("loc", ()))
    if loc and loc[0] == "body":
        loc = loc[1:]
    if kind == "json_invalid":
        return InvalidTask("", f"invalid JSON: {first.get('ctx', {}).get('error', first.get('msg', ''))}")
    if kind == "union_tag_invalid":
        ctx = first.get("ctx", {})
        return InvalidTask("kind", f"unknown kind {ctx.get('tag')!r} (expected one of {', '.join(KINDS)})")
    if kind == "union_tag_not_found":
        return InvalidTask("kind", f"missing (expected one of {', '.join(KINDS)})")
    if kind == "model_type" and not loc:
        return InvalidTask("", "expected a JSON object")
    msg = str(first.get("msg", "invalid"))
    msg = msg.removeprefix("Value error, ")
    if kind == "missing":
        msg = "missing"
    elif kind == "extra_forbidden":
        msg = "unknown field"
    path = field_path(loc)
    m = re.match(r"^([A-Za-z_][\w\[\]\.]*): (.*)$", msg, re.S)
    if not path and m is not None:  # a model validator's "<field>: <reason>"
        return InvalidTask(m.group(1), m.group(2))
    if kind in ("model_type", "model_attributes_type") or "valid dictionary" in msg:
        msg = "expected a JSON object"
    return InvalidTask(path, msg[:1].lower() + msg[1:])


def parse_spec(data: object) -> TaskSpec:
    """Validate a parsed JSON object; :class:`~fleet.errors.InvalidTask` naming the field."""
    try:
        return TASK_SPEC.validate_python(data)
    except ValidationError as e:
        raise explain(e) from None


def spec_dict(spec: TaskSpec) -> dict[str, Any]:
    """The spec as JSON-ready values (defaults left out)."""
    d: dict[str, Any] = dict(
        TASK_SPEC.dump_python(spec, mode="json", exclude_none=True, exclude_defaults=True)
    )
    d["kind"] = spec.kind
    return d


__all__ = [
    "KINDS",
    "ChargeSpec",
    "GoToSpec",
    "InspectionSpec",
    "InspectionStop",
    "ParkSpec",
    "PatrolSpec",
    "PickSpec",
    "PoseRef",
    "TaskSpec",
    "parse_spec",
    "spec_dict",
]
