"""Build a robot's py_trees tree from BehaviorTree.CPP v4 XML (Groot2's and Nav2's format).

::

    from nodes.xml_tree import load_tree
    tree = load_tree("trees/patrol.xml", "/robot1", backend, clock, battery)
    tree.root.tick_once()

Every element is looked up in a :class:`~nodes.registry.NodeRegistry` (default:
:func:`nodes.catalog.default_registry`: BehaviorTree.CPP's control nodes, Nav2's nodes, this
project's leaves), its attributes bound to the node's ports (:mod:`nodes.ports`: literals
converted now, ``{key}`` references to the robot's blackboard), its children built first.
``<SubTree ID="X" .../>`` builds tree ``X`` in a scope of its own (remapping and
``_autoremap`` as BehaviorTree.CPP). The engine is py_trees; leaves keep the project's
contract (start goals in ``initialise``, poll in ``update``, cancel in ``terminate`` only when
RUNNING).

Every mistake raises :class:`~fleet.errors.TreeError` naming the file, the line and the node:
an unknown node (with the closest names), an attribute that is not a port of the node, a
missing required port, a literal of the wrong type, an output port given a literal, a wrong
number of children, an unknown or recursive subtree, BehaviorTree.CPP scripting attributes
(``_skipIf`` ...), which this loader does not run.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

from py_trees.behaviour import Behaviour

from fleet.errors import TreeError
from fleet.navigation import Clock, NavigationBackend
from fleet.robots import BatteryModel
from fleet.types import TreeKind
from nodes.blackboard import clear_robot_blackboard, normalize_namespace, robot_blackboard
from nodes.bt_xml import GENERIC_TAGS, BtDocument, BtTree, XmlElement, parse_file, parse_text
from nodes.catalog import default_registry
from nodes.ports import Binding, Direction, Literal, Port, Ports, Scope, reference
from nodes.registry import BuildContext, NodeArgs, NodeRegistry, NodeSpec, TreeParams

#: Attributes every element may carry besides its ports.
COMMON_ATTRS = ("name", "ID", "_description", "_uid", "_fullpath")
#: BehaviorTree.CPP's scripting attributes, which this loader does not run.
SCRIPT_ATTRS = (
    "_skipIf",
    "_successIf",
    "_failureIf",
    "_while",
    "_onSuccess",
    "_onFailure",
    "_onHalted",
    "_post",
)
SUBTREE_TAGS = ("SubTree", "SubTreePlus")
#: The namespace of the robot :func:`check_tree_file` builds a tree for.
CHECK_NAMESPACE = "/_tree_check"


@dataclass
class XmlTree:
    """A tree built from XML: its ``root`` behaviour, the ``document`` it came from and the
    robot blackboard keys it reads or writes (short names, e.g. ``route``)."""

    root: Behaviour
    document: BtDocument
    keys: set[str] = field(default_factory=set)

    @property
    def task_kind(self) -> TreeKind:
        """The orders the tree works on: ``picking`` if it uses the blackboard ``pick``,
        else ``patrol`` (the coordinator hands it routes)."""
        return TreeKind.PICKING if "pick" in self.keys else TreeKind.PATROL


def load_tree(
    source: str | Path,
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel | None = None,
    *,
    registry: NodeRegistry | None = None,
    blackboard: str | None = None,
    params: TreeParams | None = None,
) -> XmlTree:
    """Build the main tree of the XML file ``source`` for robot ``namespace``.

    Args:
        source: a file path, or XML text (a string starting with ``<``).
        namespace, backend, clock: the robot's (``clock`` times RateController, Timeout ...).
        battery: the thresholds of ``BatteryLow`` / ``Charge`` (default ``BatteryModel()``).
        registry: the nodes (default :func:`nodes.catalog.default_registry`).
        blackboard: the blackboard prefix of the tree's keys (default: the robot's namespace,
            where the fleet's agent writes ``route``, ``pick``, ``charger`` ...).
        params: node parameters Nav2 keeps on the navigator (:class:`~nodes.registry.TreeParams`).

    Raises :class:`~fleet.errors.TreeError` (file, line, node, reason) for any mistake.
    """
    text = str(source)
    doc = parse_text(text) if text.lstrip().startswith("<") else parse_file(source)
    ns = normalize_namespace(namespace)
    robot_blackboard(ns, name=f"{ns}-xml")
    builder = _Builder(
        registry or default_registry(),
        ns,
        backend,
        clock,
        battery or BatteryModel(),
        params or TreeParams(),
        doc,
    )
    top = Scope(blackboard or ns)
    root = builder.tree(doc.main_tree, top, ())
    return XmlTree(root, doc, builder.keys)


class _Unbound:
    """The backend of a tree built only to be checked: it is never driven."""

    namespace = CHECK_NAMESPACE

    def _fail(self, *_args: object) -> NoReturn:
        raise TreeError("<check>", 0, "", "a tree built by check_tree_file cannot drive a robot")

    send_goal = goal_state = cancel_goal = robot_state = _fail


def check_tree_file(path: str | Path, battery: BatteryModel | None = None) -> XmlTree:
    """Build the main tree of ``path`` once for a robot that is never driven, so a bad file is
    a :class:`~fleet.errors.TreeError` before any robot runs; the result tells which orders
    the tree works on (:attr:`XmlTree.task_kind`). The check's blackboard keys are removed."""
    from fleet.clock import SimClock

    try:
        return load_tree(path, CHECK_NAMESPACE, _Unbound(), SimClock(), battery)
    finally:
        clear_robot_blackboard(CHECK_NAMESPACE)


def suggest(name: str, known: Iterable[str]) -> str:
    """``"; did you mean A or B?"`` for the known names closest to ``name`` ("" if none)."""
    close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.6)
    return f"; did you mean {' or '.join(close)}?" if close else ""


class _Builder:
    def __init__(
        self,
        registry: NodeRegistry,
        ns: str,
        backend: NavigationBackend,
        clock: Clock,
        battery: BatteryModel,
        params: TreeParams,
        doc: BtDocument,
    ) -> None:
        self.registry = registry
        self.ns = ns
        self.backend = backend
        self.clock = clock
        self.battery = battery
        self.params = params
        self.doc = doc
        self.keys: set[str] = set()
        self._instances = 0

    def tree(self, tree: BtTree, scope: Scope, chain: tuple[str, ...]) -> Behaviour:
        return self.node(tree.root, tree.file, scope, (*chain, tree.tree_id))

    def node(self, el: XmlElement, file: str, scope: Scope, chain: tuple[str, ...]) -> Behaviour:
        if el.tag in SUBTREE_TAGS:
            return self.subtree(el, file, scope, chain)
        name = el.node_name
        if el.tag in GENERIC_TAGS and not name:
            raise TreeError(file, el.line, el.label, f"a generic <{el.tag}> needs the node's name in ID")
        spec = self.registry.get(name)
        if spec is None:
            raise TreeError(
                file, el.line, el.label, f"unknown node {name!r}{suggest(name, self.registry.names())}"
            )
        if el.tag in GENERIC_TAGS and el.tag != spec.category.value:
            raise TreeError(file, el.line, el.label, f"{name} is a {spec.category.value}, not a {el.tag}")
        self._check_children(el, file, spec)
        ports = self.bind(el, file, spec, scope)
        children = [self.node(c, file, scope, chain) for c in el.children]
        ctx = BuildContext(file, self.ns, self.backend, self.clock, self.battery, scope, self.params)
        try:
            return spec.build(NodeArgs(el.attrs.get("name") or name, ports, children, ctx))
        except (ValueError, TypeError) as e:
            raise TreeError(file, el.line, el.label, str(e)) from None

    def _check_children(self, el: XmlElement, file: str, spec: NodeSpec) -> None:
        lo, hi = spec.children
        n = len(el.children)
        if lo <= n and (hi is None or n <= hi):
            return
        if hi == 0:
            want = "no children"
        elif hi == lo:
            want = f"exactly {lo} {'child' if lo == 1 else 'children'}"
        elif hi is None:
            want = f"at least {lo} {'child' if lo == 1 else 'children'}"
        else:
            want = f"{lo} to {hi} children"
        raise TreeError(file, el.line, el.label, f"{spec.category.value} {spec.name} takes {want}, found {n}")

    def bind(self, el: XmlElement, file: str, spec: NodeSpec, scope: Scope) -> Ports:
        """Bind the element's attributes to the spec's ports (see the module docstring)."""
        for attr in el.attrs:
            if attr in SCRIPT_ATTRS:
                raise TreeError(
                    file, el.line, el.label, f"{attr}: BehaviorTree.CPP scripting is not supported"
                )
            if attr not in COMMON_ATTRS and spec.port(attr) is None:
                ports = ", ".join(p.name for p in spec.ports) or "none"
                raise TreeError(
                    file,
                    el.line,
                    el.label,
                    f"{spec.name} has no port {attr!r}{suggest(attr, [p.name for p in spec.ports])} (ports: {ports})",
                )
        bindings = []
        for port in spec.ports:
            text = el.attrs.get(port.name)
            if text is None and port.required:
                raise TreeError(file, el.line, el.label, f"port {port.name!r} is required ({port.type.doc})")
            try:
                bindings.append(self._binding(port, text if text is not None else port.default, scope))
            except ValueError as e:
                given = "given" if text is not None else "default"
                raise TreeError(file, el.line, el.label, f"port {port.name!r} ({given}): {e}") from None
        return Ports(bindings)

    def _binding(self, port: Port, text: str | None, scope: Scope) -> Binding:
        if text is None:
            return Binding(port)
        key = reference(text, port.name)
        if key is None:
            if port.direction is not Direction.IN:
                raise ValueError(
                    f"an {port.direction.value} port needs a blackboard key such as {{{port.name}}}, got {text!r}"
                )
            if text.strip() == '""':
                text = ""
            return Binding(
                port, value=port.type.parse_text(text) if text or port.type.type_name == "string" else None
            )
        base, *attrs = key.split(".")
        target = scope.resolve(base)
        if isinstance(target, Literal):
            if port.direction is not Direction.IN or attrs:
                raise ValueError(f"{{{base}}} is the literal {target.text!r} in this subtree, not a key")
            return Binding(port, value=port.type.parse_text(target.text))
        if target.startswith(self.ns + "/") and "/" not in target[len(self.ns) + 1 :]:
            self.keys.add(target[len(self.ns) + 1 :])
        return Binding(port, storage=target, attrs=tuple(attrs))

    def subtree(self, el: XmlElement, file: str, scope: Scope, chain: tuple[str, ...]) -> Behaviour:
        tid = el.attrs.get("ID", "")
        tree = self.doc.trees.get(tid)
        if tree is None:
            known = list(self.doc.trees)
            raise TreeError(
                file,
                el.line,
                el.label,
                f"no tree with ID {tid!r}{suggest(tid, known)} (trees: {', '.join(known)})",
            )
        if tid in chain:
            raise TreeError(file, el.line, el.label, f"subtree recursion: {' -> '.join((*chain, tid))}")
        if el.children:
            raise TreeError(file, el.line, el.label, "a <SubTree> has no children")
        remap: dict[str, str | Literal] = {}
        autoremap = False
        for attr, value in el.attrs.items():
            if attr in ("ID", "name", "_description", "_uid", "_fullpath"):
                continue
            if attr == "_autoremap":
                autoremap = value.strip().lower() in ("true", "1")
                continue
            if attr.startswith("_"):
                raise TreeError(file, el.line, el.label, f"{attr}: not supported on a <SubTree>")
            try:
                key = reference(value, attr)
            except ValueError as e:
                raise TreeError(file, el.line, el.label, f"{attr}: {e}") from None
            remap[attr] = Literal(value) if key is None else key
        self._instances += 1
        child = Scope(f"{scope.prefix}/{tid}#{self._instances}", scope, remap, autoremap)
        return self.tree(tree, child, chain)
