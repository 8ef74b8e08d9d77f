"""The node registry: which XML element names build which py_trees behaviours, with which
ports (BehaviorTree.CPP's factory, for :mod:`nodes.xml_tree`).

A :class:`NodeSpec` names a node (its Nav2 / BehaviorTree.CPP name, e.g. ``ComputePathToPose``),
its :class:`Category`, its ports (:class:`nodes.ports.Port`), how many children it takes and a
``build`` function turning a :class:`NodeArgs` (the instance name, the bound ports, the built
children and the :class:`BuildContext` of the robot) into a behaviour. A build function raises
``ValueError`` for an input it cannot take; the loader reports it with the file, line and node.

:func:`nodes.catalog.default_registry` holds every node this project ships; add your own with
:meth:`NodeRegistry.register` (a copy: ``default_registry().copy()``).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from py_trees.behaviour import Behaviour

from fleet.navigation import Clock, NavigationBackend
from fleet.robots import BatteryModel
from nodes.ports import Port, Ports, Scope


class Category(enum.StrEnum):
    """BehaviorTree.CPP's node categories (also the generic XML tags)."""

    ACTION = "Action"
    CONDITION = "Condition"
    CONTROL = "Control"
    DECORATOR = "Decorator"


@dataclass(frozen=True)
class TreeParams:
    """Parameters Nav2 keeps on the bt_navigator node rather than in the XML.

    ``goal_reached_tol`` (m, GoalReached), ``transform_tolerance`` (s, unused: poses come from
    the backend), ``recoveries_key``: the blackboard key recovery behaviours count in
    (``number_recoveries``)."""

    goal_reached_tol: float = 0.25
    recoveries_key: str = "number_recoveries"


@dataclass(frozen=True)
class BuildContext:
    """What a node of one robot's tree is built with: the XML ``file``, the robot's
    ``namespace``, ``backend`` and ``clock``, its ``battery`` model (the thresholds of the
    project's ``BatteryLow``), the blackboard ``scope`` of the (sub)tree and the
    :class:`TreeParams`."""

    file: str
    namespace: str
    backend: NavigationBackend
    clock: Clock
    battery: BatteryModel
    scope: Scope
    params: TreeParams = field(default_factory=TreeParams)

    def key(self, name: str) -> str:
        """The storage name of blackboard key ``name`` of the tree's top scope."""
        resolved = self.scope.resolve("@" + name)
        assert isinstance(resolved, str)
        return resolved


@dataclass(frozen=True)
class NodeArgs:
    """One node instance to build: its ``name`` (the XML ``name``, else the node's), its bound
    ``ports``, its built ``children`` and the ``ctx``."""

    name: str
    ports: Ports
    children: list[Behaviour]
    ctx: BuildContext


Builder = Callable[[NodeArgs], Behaviour]


@dataclass(frozen=True)
class NodeSpec:
    """A node the XML may use (see the module docstring). ``children``: ``(min, max)``
    (``max`` ``None``: any number)."""

    name: str
    category: Category
    build: Builder
    ports: tuple[Port, ...] = ()
    doc: str = ""
    children: tuple[int, int | None] = (0, 0)

    def port(self, name: str) -> Port | None:
        for p in self.ports:
            if p.name == name:
                return p
        return None


def leaf(
    name: str, category: Category, build: Builder, ports: tuple[Port, ...] = (), doc: str = ""
) -> NodeSpec:
    """The spec of an action or condition (no children)."""
    return NodeSpec(name, category, build, ports, doc, (0, 0))


def decorator(name: str, build: Builder, ports: tuple[Port, ...] = (), doc: str = "") -> NodeSpec:
    """The spec of a decorator (exactly one child)."""
    return NodeSpec(name, Category.DECORATOR, build, ports, doc, (1, 1))


def control(
    name: str,
    build: Builder,
    ports: tuple[Port, ...] = (),
    doc: str = "",
    children: tuple[int, int | None] = (1, None),
) -> NodeSpec:
    """The spec of a control node (``children`` as :class:`NodeSpec`)."""
    return NodeSpec(name, Category.CONTROL, build, ports, doc, children)


class NodeRegistry:
    """Node specs by name (see the module docstring)."""

    def __init__(self, specs: tuple[NodeSpec, ...] = ()) -> None:
        self._specs: dict[str, NodeSpec] = {}
        for s in specs:
            self.register(s)

    def register(self, spec: NodeSpec, *, replace: bool = False) -> None:
        """Add ``spec``; ``ValueError`` if the name is taken (unless ``replace``)."""
        if spec.name in self._specs and not replace:
            raise ValueError(f"a node named {spec.name!r} is already registered")
        self._specs[spec.name] = spec

    def alias(self, name: str, target: str) -> None:
        """Register ``name`` as another name of the node ``target`` (e.g. BT.CPP v3 names)."""
        s = self._specs[target]
        self.register(NodeSpec(name, s.category, s.build, s.ports, f"alias of {target}", s.children))

    def get(self, name: str) -> NodeSpec | None:
        return self._specs.get(name)

    def names(self) -> list[str]:
        return sorted(self._specs)

    def copy(self) -> NodeRegistry:
        return NodeRegistry(tuple(self._specs.values()))

    def __iter__(self) -> Iterator[NodeSpec]:
        return iter(self._specs.values())

    def __len__(self) -> int:
        return len(self._specs)
