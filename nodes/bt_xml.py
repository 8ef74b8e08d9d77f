"""Reading BehaviorTree.CPP v4 XML (the format Groot2 edits and Nav2 ships) into a document:
the trees by ``ID``, the main tree, every element with its line number.

The format::

    <root BTCPP_format="4" main_tree_to_execute="MainTree">
      <include path="recoveries.xml"/>            <!-- more trees, relative to this file -->
      <BehaviorTree ID="MainTree">
        <Sequence name="...">                     <!-- exactly one root node per tree -->
          <ComputePathToPose goal="{goal}" path="{path}"/>
          <SubTree ID="Recoveries" _autoremap="true"/>
        </Sequence>
      </BehaviorTree>
      <TreeNodesModel> ... </TreeNodesModel>      <!-- Groot2's palette: ignored -->
    </root>

``BTCPP_format`` may be ``4`` or absent (Nav2 Humble and older files); ``main_tree_to_execute``
may be omitted when the file (with its includes) holds exactly one tree. A node may also be
written in the generic form ``<Action ID="Spin" .../>`` (``Action``, ``Condition``,
``Control``, ``Decorator``, ``SubTree``). What the nodes mean is :mod:`nodes.xml_tree`'s
business; this module only checks the document's shape. Every mistake raises
:class:`~fleet.errors.TreeError` naming the file and the line.
"""

from __future__ import annotations

import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

from fleet.errors import TreeError

#: Generic element names that carry the node's registered name in ``ID``.
GENERIC_TAGS = ("Action", "Condition", "Control", "Decorator")
#: How deep ``<include>`` may nest (a cycle is reported before this).
MAX_INCLUDE_DEPTH = 16


@dataclass(frozen=True)
class XmlElement:
    """One XML element: its ``tag``, attributes (in file order), ``line`` (1-based) and
    child elements (text and comments are dropped)."""

    tag: str
    attrs: dict[str, str]
    line: int
    children: tuple[XmlElement, ...] = ()

    @property
    def node_name(self) -> str:
        """The registered node this element stands for (``ID`` of a generic element)."""
        if self.tag in GENERIC_TAGS:
            return self.attrs.get("ID", "")
        return self.tag

    @property
    def label(self) -> str:
        """``<Tag name="x">`` for messages."""
        name = self.attrs.get("name")
        ident = self.attrs.get("ID") if self.tag in (*GENERIC_TAGS, "SubTree", "SubTreePlus") else None
        extra = "".join(f' {k}="{v}"' for k, v in (("ID", ident), ("name", name)) if v)
        return f"<{self.tag}{extra}>"


@dataclass(frozen=True)
class BtTree:
    """One ``<BehaviorTree ID=...>``: its root node and where it was defined."""

    tree_id: str
    root: XmlElement
    file: str
    line: int


@dataclass(frozen=True)
class BtDocument:
    """A parsed file: its trees by ``ID`` (includes merged) and the main tree's ID."""

    file: str
    trees: dict[str, BtTree] = field(default_factory=dict)
    main: str = ""

    @property
    def main_tree(self) -> BtTree:
        return self.trees[self.main]


def parse_elements(text: str, file: str) -> XmlElement:
    """The element tree of XML ``text`` with line numbers (``file`` names it in errors)."""
    parser = xml.parsers.expat.ParserCreate()
    stack: list[tuple[str, dict[str, str], int, list[XmlElement]]] = []
    done: list[XmlElement] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        stack.append((tag, dict(attrs), parser.CurrentLineNumber, []))

    def end(_tag: str) -> None:
        tag, attrs, line, children = stack.pop()
        el = XmlElement(tag, attrs, line, tuple(children))
        (stack[-1][3] if stack else done).append(el)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(text, True)
    except xml.parsers.expat.ExpatError as e:
        raise TreeError(
            file, e.lineno, "", f"not well-formed XML: {xml.parsers.expat.errors.messages[e.code]}"
        ) from None
    if not done:
        raise TreeError(file, 1, "", "no XML element")
    return done[0]


def parse_text(text: str, file: str = "<string>", base: Path | None = None) -> BtDocument:
    """The document of BT XML ``text``; ``base`` is the folder ``<include path>`` is
    relative to (default: the current folder)."""
    trees: dict[str, BtTree] = {}
    root = parse_elements(text, file)
    _collect(root, file, base or Path.cwd(), trees, (file,))
    main = root.attrs.get("main_tree_to_execute", "")
    if main:
        if main not in trees:
            raise TreeError(
                file,
                root.line,
                "<root>",
                f"main_tree_to_execute={main!r} names no tree (trees: {', '.join(sorted(trees)) or 'none'})",
            )
    elif len(trees) == 1:
        main = next(iter(trees))
    elif not trees:
        raise TreeError(file, root.line, "<root>", "the file defines no <BehaviorTree>")
    else:
        raise TreeError(
            file,
            root.line,
            "<root>",
            f"several trees ({', '.join(sorted(trees))}): say which one runs with main_tree_to_execute",
        )
    return BtDocument(file, trees, main)


def parse_file(path: str | Path) -> BtDocument:
    """The document of the BT XML file ``path`` (includes resolved relative to it)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise TreeError(str(p), 0, "", f"cannot read the file: {e.strerror or e}") from None
    return parse_text(text, str(p), p.parent)


def _collect(
    root: XmlElement, file: str, base: Path, trees: dict[str, BtTree], chain: tuple[str, ...]
) -> None:
    """Add the trees of ``root`` (a ``<root>`` element) and of its includes to ``trees``."""
    if root.tag != "root":
        raise TreeError(file, root.line, f"<{root.tag}>", "the top element must be <root>")
    fmt = root.attrs.get("BTCPP_format")
    if fmt not in (None, "4"):
        raise TreeError(file, root.line, "<root>", f'BTCPP_format="{fmt}" is not supported (only "4")')
    for el in root.children:
        if el.tag == "BehaviorTree":
            _tree(el, file, trees)
        elif el.tag == "include":
            _include(el, file, base, trees, chain)
        elif el.tag != "TreeNodesModel":
            raise TreeError(
                file, el.line, el.label, "expected <BehaviorTree>, <include> or <TreeNodesModel> under <root>"
            )


def _tree(el: XmlElement, file: str, trees: dict[str, BtTree]) -> None:
    tid = el.attrs.get("ID", "")
    if not tid:
        raise TreeError(file, el.line, "<BehaviorTree>", "a <BehaviorTree> needs an ID")
    if tid in trees:
        first = trees[tid]
        raise TreeError(
            file, el.line, el.label, f"tree {tid!r} is defined twice (first at {first.file}:{first.line})"
        )
    if len(el.children) != 1:
        raise TreeError(
            file,
            el.line,
            f'<BehaviorTree ID="{tid}">',
            f"a tree has exactly one root node, found {len(el.children)}",
        )
    trees[tid] = BtTree(tid, el.children[0], file, el.line)


def _include(el: XmlElement, file: str, base: Path, trees: dict[str, BtTree], chain: tuple[str, ...]) -> None:
    rel = el.attrs.get("path", "")
    if not rel:
        raise TreeError(file, el.line, "<include>", "an <include> needs a path")
    target = (base / rel).resolve()
    if str(target) in chain or len(chain) > MAX_INCLUDE_DEPTH:
        raise TreeError(file, el.line, "<include>", f"include cycle: {' -> '.join((*chain, str(target)))}")
    try:
        text = target.read_text(encoding="utf-8")
    except OSError as e:
        raise TreeError(file, el.line, "<include>", f"cannot read {target}: {e.strerror or e}") from None
    _collect(parse_elements(text, str(target)), str(target), target.parent, trees, (*chain, str(target)))
