"""Check the package layout of docs/architecture.md: what each package may import, no import
cycle (imports inside functions included), no module over MAX_LINES and no function over
MAX_FUNC_LINES unless a ``# long: <reason>`` comment stands on the line above its ``def``.

    python tools/check_layout.py          # exit 1 and one line per problem if any

Imports under ``if TYPE_CHECKING:`` count too, for the rules and for cycles.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("fleet", "nodes", "sim")
MAX_LINES = 600
MAX_FUNC_LINES = 80

#: The core: every other part of the project may import these.
CORE = (
    "fleet.types",
    "fleet.errors",
    "fleet.navigation",
    "fleet.wake",
    "fleet.clock",
    "fleet.robots",
    "fleet.maps",
    "fleet.yamlfile",
    "fleet.messages",
    "fleet.diagnostics",
)
#: Unit -> the units it may import besides itself and the core (a unit is a module or package).
ALLOWED: dict[str, tuple[str, ...]] = {
    "fleet.types": (),
    "fleet.errors": (),
    "fleet.navigation": (),
    "fleet.wake": (),
    "fleet.clock": (),
    "fleet.robots": (),
    "fleet.maps": (),
    "fleet.yamlfile": (),
    "fleet.messages": (),
    "fleet.diagnostics": (),
    "fleet.roadmap": (),
    "fleet.config": ("fleet.roadmap",),
    "fleet.coordination": ("fleet.roadmap", "fleet.config"),
    "fleet.traffic": ("fleet.roadmap", "fleet.config", "fleet.coordination"),
    "fleet.bus": (),
    "fleet.viz": ("fleet.roadmap", "fleet.config"),
    "fleet.dashboard": (),
    "fleet.testing": (),
    "fleet.service": ("fleet.roadmap", "fleet.config", "fleet.coordination", "fleet.bus"),
    "fleet.api": ("fleet.roadmap", "fleet.config", "fleet.coordination", "fleet.service"),
    "fleet.client": (),
    "fleet.warehouse": ("fleet.roadmap", "fleet.config"),
    "nodes": ("fleet.traffic",),
    "sim": (),
    "sim.sumo": ("sim", "fleet.roadmap", "fleet.config"),
    "fleet.runtime": (
        "fleet.roadmap",
        "fleet.config",
        "fleet.coordination",
        "fleet.traffic",
        "fleet.bus",
        "fleet.viz",
        "fleet.service",
        "fleet.api",
        "nodes",
        "sim",
    ),
    "fleet.ros": ("fleet.roadmap", "fleet.config", "fleet.runtime", "fleet.bus", "fleet.viz", "nodes", "sim"),
    "fleet.loadtest": (
        "fleet.roadmap",
        "fleet.config",
        "fleet.coordination",
        "fleet.traffic",
        "fleet.bus",
        "fleet.viz",
        "fleet.runtime",
        "fleet.warehouse",
        "nodes",
        "sim",
    ),
    "fleet.chaos": ("fleet.bus",),
    "fleet.cli": ("*",),
    "fleet": (),
}


def modules() -> Iterator[tuple[str, Path]]:
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            yield ".".join(parts), path


def unit_of(module: str) -> str:
    """The most specific key of ALLOWED that ``module`` is, or is inside."""
    best = ""
    for unit in ALLOWED:
        if (module == unit or module.startswith(unit + ".")) and len(unit) > len(best):
            best = unit
    return best or module


def imports(tree: ast.Module, module: str, is_pkg: bool) -> Iterator[tuple[str, int, bool]]:
    """``(imported module, line, under TYPE_CHECKING)`` for every project import."""
    guarded: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for sub in ast.walk(node):
                guarded.add(id(sub))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in PACKAGES:
                    yield a.name, node.lineno, id(node) in guarded
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            if name.split(".")[0] not in PACKAGES:
                continue
            for a in node.names:  # ``from pkg import submodule``
                yield name, node.lineno, id(node) in guarded
                yield f"{name}.{a.name}", node.lineno, id(node) in guarded


def main() -> int:
    problems: list[str] = []
    known = dict(modules())
    graph: dict[str, set[str]] = {m: set() for m in known}
    for mod, path in known.items():
        src = path.read_text()
        lines = src.splitlines()
        rel = path.relative_to(ROOT)
        if len(lines) > MAX_LINES:
            problems.append(f"{rel}: {len(lines)} lines (at most {MAX_LINES})")
        tree = ast.parse(src)
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                above = lines[first - 2].strip() if first >= 2 else ""
                if n > MAX_FUNC_LINES and not above.startswith("# long:"):
                    problems.append(
                        f"{rel}:{node.lineno}: function {node.name} has {n} lines (at most {MAX_FUNC_LINES}, "
                        "or a '# long: <reason>' comment above it)"
                    )
        me = unit_of(mod)
        allowed = ALLOWED.get(me, ())
        for target, lineno, _guarded in imports(tree, mod, path.name == "__init__.py"):
            if target not in known:
                continue
            if target != mod:
                graph[mod].add(target)
            other = unit_of(target)
            if other == me or target in CORE or other in CORE or "*" in allowed or other in allowed:
                continue
            problems.append(
                f"{rel}:{lineno}: {me} may not import {target} (allowed: core + {', '.join(allowed) or 'nothing'})"
            )
    for cycle in cycles(graph):
        problems.append("import cycle: " + " -> ".join([*cycle, cycle[0]]))
    for p in problems:
        print(p)
    return 1 if problems else 0


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


if __name__ == "__main__":
    sys.exit(main())
