"""Reading the YAML of config and map files safely: :func:`parse_yaml`.

A safe loader (plain values only: mappings, lists, strings, numbers, booleans, null) with two
rules a user's file must also follow:

- nesting is at most :data:`MAX_DEPTH` levels deep: a deeper document is refused before it is
  built (a document nested 100,000 levels deep would otherwise overflow the C stack of the
  YAML library and kill the process);
- a key appears at most once in each mapping: plain YAML keeps the last value of a repeated
  key, silently dropping the first.

libyaml scans and parses the text when it is installed (fast); the nodes are composed here,
counting the depth and the keys on the way.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from yaml import YAMLError
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.events import Event, MappingEndEvent, MappingStartEvent, SequenceEndEvent, SequenceStartEvent
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode
from yaml.parser import Parser
from yaml.reader import Reader
from yaml.resolver import Resolver
from yaml.scanner import Scanner

#: The deepest nesting of mappings and lists accepted (a fleet config needs 5).
MAX_DEPTH = 64


class _PyParser(Reader, Scanner, Parser):
    """The pure-Python scanner and parser, used without libyaml."""

    def __init__(self, stream: str) -> None:
        Reader.__init__(self, stream)
        Scanner.__init__(self)
        Parser.__init__(self)


if TYPE_CHECKING:
    _Parser = _PyParser
else:
    try:  # libyaml's scanner and parser when installed: the same events, faster
        from yaml.cyaml import CParser as _Parser
    except ImportError:
        _Parser = _PyParser


class YamlProblem(Exception):
    """A document breaks a rule of :func:`parse_yaml`: ``field`` (``roadmap.nodes.w_s``, empty
    for the whole document) and ``reason``."""

    def __init__(self, field: str, reason: str) -> None:
        self.field, self.reason = field, reason
        super().__init__(f"{field}: {reason}" if field else reason)


if TYPE_CHECKING:

    class _Events(Parser, Resolver):
        """What the composer uses of the parser and the resolver the loader is made of."""

        def peek_event(self) -> Event: ...
        def get_event(self) -> Any: ...
        def resolve(self, kind: type[Node], value: str | None, implicit: object) -> str: ...

else:
    _Events = object


class _Composer(Composer, _Events):
    """Composes nodes from parser events, tracking the path of the node being composed."""

    _path: list[str | int]

    def compose_node(self, parent: Node | None, index: object) -> Node | None:
        if self.check_event(MappingStartEvent, SequenceStartEvent) and len(self._path) >= MAX_DEPTH:
            mark = self.peek_event().start_mark
            line = f" (line {mark.line + 1})" if mark is not None else ""
            raise YamlProblem(_field(self._path[:1]), f"nested more than {MAX_DEPTH} levels deep{line}")
        node: Node | None = super().compose_node(parent, index)  # type: ignore[arg-type]  # stub: int
        return node

    def compose_sequence_node(self, anchor: str | None) -> SequenceNode:  # type: ignore[override]
        start = self.get_event()
        tag = (
            start.tag
            if start.tag is not None and start.tag != "!"
            else self.resolve(SequenceNode, None, start.implicit)
        )
        node = SequenceNode(tag, [], start.start_mark, None, flow_style=start.flow_style)
        if anchor is not None:
            self.anchors[anchor] = node
        while not self.check_event(SequenceEndEvent):
            self._path.append(len(node.value))
            node.value.append(self.compose_node(node, len(node.value)))
            self._path.pop()
        node.end_mark = self.get_event().end_mark
        return node

    def compose_mapping_node(self, anchor: str | None) -> MappingNode:  # type: ignore[override]
        start = self.get_event()
        tag = (
            start.tag
            if start.tag is not None and start.tag != "!"
            else self.resolve(MappingNode, None, start.implicit)
        )
        node = MappingNode(tag, [], start.start_mark, None, flow_style=start.flow_style)
        if anchor is not None:
            self.anchors[anchor] = node
        seen: dict[tuple[str, str], int] = {}
        while not self.check_event(MappingEndEvent):
            key = self.compose_node(node, None)
            if isinstance(key, ScalarNode) and key.tag != "tag:yaml.org,2002:merge":
                line = key.start_mark.line + 1
                known = len(seen)
                first = seen.setdefault((key.tag, key.value), line)
                if len(seen) == known:
                    raise YamlProblem(
                        _field([*self._path, key.value]),
                        f"key {key.value!r} appears twice ({_lines(first, line)}): "
                        "YAML would keep only the last",
                    )
            self._path.append(key.value if isinstance(key, ScalarNode) else "?")
            value = self.compose_node(node, key)
            self._path.pop()
            node.value.append((key, value))
        node.end_mark = self.get_event().end_mark
        return node


class _Loader(_Composer, _Parser, SafeConstructor, Resolver):
    def __init__(self, text: str) -> None:
        _Parser.__init__(self, text)
        Composer.__init__(self)
        SafeConstructor.__init__(self)
        Resolver.__init__(self)
        self._path = []


def _lines(first: int, then: int) -> str:
    return f"line {first}" if first == then else f"lines {first} and {then}"


def _field(path: list[str | int]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else f".{part}" if out else str(part)
    return out


def parse_yaml(text: str) -> object:
    """The single YAML document in ``text`` as plain Python values (``None`` if empty).

    Raises :class:`YamlProblem` for nesting deeper than :data:`MAX_DEPTH` or a key repeated in
    a mapping (field: where), and ``yaml.YAMLError`` for text that is not YAML.
    """
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except YAMLError as e:
        # PyYAML >= 6.0.4 stops scanning at its own depth limit (1000), and its scanner reads
        # ahead of the nodes composed here: the same problem, named the same way
        if "maximum nesting depth" not in str(e):
            raise
        mark = getattr(e, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        raise YamlProblem(
            _field(loader._path[:1]), f"nested more than {MAX_DEPTH} levels deep{line}"
        ) from None
    finally:
        loader.dispose()
