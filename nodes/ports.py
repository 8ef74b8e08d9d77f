"""Ports: how a node loaded from XML reads its inputs and writes its outputs.

A node declares its ports (:class:`Port`: name, :class:`PortType`, direction, default). In the
XML each port is given either a **literal** (``spin_dist="1.57"``: converted once, at load
time, so a bad number is a load error naming the file, line, node and port) or a **blackboard
reference** (``goal="{goal}"``: read or written at tick time). ``{=}`` refers to the key named
like the port; ``{@key}`` to the key in the robot's top blackboard (through any subtree);
``{pick.shelf}`` (an extension of this project) reads the attribute ``shelf`` of the value of
``pick``.

Keys live in py_trees' process-global blackboard under a :class:`Scope`: the top scope of a
robot's tree is the robot's namespace (``{route}`` is ``/robot1/route``, the key the fleet's
agent writes); a subtree gets its own scope (``<prefix>/<subtree>#<n>``) whose keys are private
unless remapped (``<SubTree ID="X" goal="{goal}"/>``, ``_autoremap="true"``) or set to a literal
(``<SubTree ID="X" wait="5"/>``), as in BehaviorTree.CPP.

A value read from the blackboard that is a string (a literal written by ``SetBlackboard``,
or passed into a subtree) is converted with the port's type when it is read. A key that was
never written reads as missing: :meth:`Ports.get` returns ``None``.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from py_trees.blackboard import Blackboard

from fleet.types import Mode, Pose2D

_MISSING = object()
_KEY = re.compile(r"^@?[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


class Direction(enum.StrEnum):
    """Which way a port carries data."""

    IN = "input"
    OUT = "output"
    INOUT = "inout"


def _float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"{text!r} is not a finite number")
    return v


def _bool(text: str) -> bool:
    t = text.strip().lower()
    if t in ("true", "1"):
        return True
    if t in ("false", "0"):
        return False
    raise ValueError(f"{text!r} is not true or false")


def _pose(text: str) -> Pose2D:
    parts = [p for p in text.replace(",", ";").split(";") if p.strip()]
    if len(parts) not in (2, 3):
        raise ValueError(f"{text!r} is not a pose 'x;y;theta' (m, m, rad)")
    vals = [_float(p) for p in parts]
    return Pose2D(vals[0], vals[1], vals[2] if len(vals) == 3 else 0.0)


def _poses(text: str) -> tuple[Pose2D, ...]:
    return tuple(_pose(p) for p in text.split("|") if p.strip())


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.replace(",", ";").split(";") if p.strip())


def _words(text: str) -> tuple[str, ...]:
    return tuple(p.strip() for p in text.replace(",", ";").split(";") if p.strip())


def _mode(text: str) -> Mode:
    try:
        return Mode(text.strip())
    except ValueError:
        raise ValueError(f"{text!r} is not a mode ({', '.join(m.value for m in Mode)})") from None


class PortType(enum.Enum):
    """The type of a port's value and how a literal of it is written in the XML."""

    FLOAT = ("double", _float, "a number")
    INT = ("int", int, "an integer")
    BOOL = ("bool", _bool, "true or false")
    STRING = ("string", str, "text")
    POSE = ("pose", _pose, "a pose 'x;y;theta' (m, m, rad) in the map frame")
    POSES = ("poses", _poses, "poses 'x;y;theta|x;y;theta|...'")
    PATH = ("path", _poses, "a path: poses 'x;y;theta|...'")
    INTS = ("ints", _ints, "integers '101;107'")
    KEYS = ("keys", _words, "blackboard keys 'task_id;route'")
    MODE = ("mode", _mode, "a robot mode (idle, patrol, picking, charging, recovery)")
    ANY = ("any", str, "any value")

    def __init__(self, type_name: str, parse: Callable[[str], object], doc: str) -> None:
        self.type_name = type_name
        self.parse_text = parse
        self.doc = doc

    def convert(self, value: object) -> object:
        """``value`` as this type: strings are parsed (ValueError if they do not parse), other
        values are returned as they are."""
        if isinstance(value, str) and self is not PortType.STRING and self is not PortType.ANY:
            return self.parse_text(value)
        return value


@dataclass(frozen=True)
class Port:
    """A port of a node: ``name``, ``type``, ``direction``, the ``default`` written as in the
    XML (``None``: no default) and whether the XML must give it (``required``)."""

    name: str
    type: PortType
    direction: Direction = Direction.IN
    default: str | None = None
    required: bool = False
    doc: str = ""


def in_port(
    name: str, type_: PortType, default: str | None = None, doc: str = "", *, required: bool = False
) -> Port:
    return Port(name, type_, Direction.IN, default, required, doc)


def out_port(name: str, type_: PortType, default: str | None = None, doc: str = "") -> Port:
    return Port(name, type_, Direction.OUT, default, False, doc)


# -- scopes ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Literal:
    """A literal a subtree's key was set to (``<SubTree ID="X" key="text"/>``)."""

    text: str


class Scope:
    """Where a tree's blackboard keys live (see the module docstring).

    ``prefix``: the storage prefix of this scope's own keys; ``parent``: the scope of the
    tree that uses this subtree (``None`` at the top); ``remap``: subtree key -> the parent's
    key or a literal; ``autoremap``: unlisted keys are the parent's."""

    def __init__(
        self,
        prefix: str,
        parent: Scope | None = None,
        remap: dict[str, str | Literal] | None = None,
        autoremap: bool = False,
    ) -> None:
        self.prefix = prefix.rstrip("/")
        self.parent = parent
        self.remap = dict(remap or {})
        self.autoremap = autoremap

    @property
    def top(self) -> Scope:
        s = self
        while s.parent is not None:
            s = s.parent
        return s

    def resolve(self, key: str) -> str | Literal:
        """The storage name of ``key`` (``/robot1/goal``), or the literal it was set to."""
        if key.startswith("@"):
            return self.top.resolve(key[1:])
        if self.parent is not None:
            if key in self.remap:
                target = self.remap[key]
                return target if isinstance(target, Literal) else self.parent.resolve(target)
            if self.autoremap:
                return self.parent.resolve(key)
        return f"{self.prefix}/{key}"


def reference(text: str, port: str) -> str | None:
    """The key of a blackboard reference ``{key}`` (``{=}`` is ``port``), else ``None``
    for a literal. ValueError for a malformed key."""
    t = text.strip()
    if not (t.startswith("{") and t.endswith("}")):
        return None
    key = t[1:-1].strip()
    if key == "=":
        return port
    if not _KEY.match(key):
        raise ValueError(f"{t!r} is not a blackboard key (letters, digits and _, e.g. {{goal}})")
    return key


# -- bound ports -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Binding:
    """How one port of one node instance is bound: a constant, a blackboard entry (its storage
    name and the attribute path read from its value), or nothing."""

    port: Port
    value: object = _MISSING
    storage: str | None = None
    attrs: tuple[str, ...] = ()

    @property
    def bound(self) -> bool:
        return self.storage is not None or self.value is not _MISSING


class Ports:
    """The bound ports of one node instance (built by :mod:`nodes.xml_tree`).

    :meth:`get` reads an input (``None`` when it is unbound or its key was never written);
    :meth:`set` writes an output (a no-op when it is unbound); :meth:`given` says whether the
    XML (or a default) bound the port."""

    def __init__(self, bindings: Iterable[Binding] = ()) -> None:
        self._b = {b.port.name: b for b in bindings}

    def has(self, name: str) -> bool:
        """Whether the node declares the port ``name``."""
        return name in self._b

    def put(self, name: str, value: object) -> None:
        """:meth:`set` for a port the node may not declare (then nothing happens)."""
        if name in self._b:
            self.set(name, value)

    def given(self, name: str) -> bool:
        b = self._b.get(name)
        return b is not None and b.bound

    def key(self, name: str) -> str | None:
        """The storage name a port is bound to (``None``: a constant or unbound)."""
        b = self._b.get(name)
        return None if b is None else b.storage

    def get(self, name: str) -> object:
        b = self._b.get(name)
        if b is None:
            raise KeyError(f"no port {name!r}")
        if b.storage is None:
            return None if b.value is _MISSING else b.value
        value = Blackboard.storage.get(b.storage, _MISSING)
        for attr in b.attrs:
            if value is _MISSING or value is None:
                break
            value = getattr(value, attr, _MISSING)
        if value is _MISSING or value is None:
            return None
        return b.port.type.convert(value)

    def set(self, name: str, value: object) -> None:
        b = self._b.get(name)
        if b is None:
            raise KeyError(f"no port {name!r}")
        if b.storage is not None:
            Blackboard.storage[b.storage] = value

    def get_float(self, name: str, default: float = 0.0) -> float:
        v = self.get(name)
        return float(v) if isinstance(v, (int, float)) else default

    def get_int(self, name: str, default: int = 0) -> int:
        v = self.get(name)
        return int(v) if isinstance(v, (int, float)) else default

    def get_bool(self, name: str, default: bool = False) -> bool:
        v = self.get(name)
        return bool(v) if v is not None else default

    def get_pose(self, name: str) -> Pose2D | None:
        v = self.get(name)
        return v if isinstance(v, Pose2D) else None

    def get_poses(self, name: str) -> tuple[Pose2D, ...] | None:
        v = self.get(name)
        if v is None:
            return None
        if isinstance(v, (tuple, list)):
            return tuple(p for p in v if isinstance(p, Pose2D))
        return None

    def get_str(self, name: str, default: str = "") -> str:
        v = self.get(name)
        return default if v is None else str(v)
