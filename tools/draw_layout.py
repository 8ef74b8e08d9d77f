"""Draw the package layout (docs/img/layout.png) from the code's own imports.

One box per unit of tools/check_layout.py (a package, or a module of the core), stacked so that
every arrow points down: a unit stands above everything it imports. Arrows are the imports
between units after transitive reduction (an import implied by a longer chain of arrows is not
drawn). The core (the modules every unit may import) is the bottom row.

    python tools/draw_layout.py [--out docs/img/layout.png]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import networkx as nx  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from check_layout import ALLOWED, CORE, ROOT, imports, modules, unit_of  # noqa: E402

#: Units drawn, and the one line under each name.
SHOWN: dict[str, str] = {
    "fleet.cli": "one module per command",
    "fleet.api": "HTTP + WebSocket API (FastAPI)",
    "fleet.dashboard": "live web dashboard",
    "fleet.service": "task service, durable store",
    "fleet.client": "FleetClient (Python API)",
    "fleet.loadtest": "generated fleets, time series",
    "fleet.chaos": "kill -9 at random, verdicts",
    "fleet.ros": "ROS 2 / Nav2 edge",
    "fleet.runtime": "worlds, agents, runner, report",
    "sim.sumo": "SUMO backend (libsumo)",
    "nodes": "behavior-tree nodes, trees",
    "fleet.traffic": "reservations, grants, deadlocks",
    "fleet.coordination": "task book, matching, health",
    "fleet.bus": "Zenoh sessions, status bus, nav protocol",
    "fleet.viz": "live table, plots",
    "fleet.warehouse": "generated warehouses",
    "sim": "kinematic simulator",
    "fleet.config": "schema, loading, checks",
    "fleet.roadmap": "graph, docks, distances",
    "fleet.testing": "backend conformance checker",
    "fleet.types": "poses, goals, states, enums",
    "fleet.navigation": "the backend contract",
    "fleet.messages": "wire messages + codec",
    "fleet.clock": "clocks, pacer",
    "fleet.robots": "robot, battery models",
    "fleet.maps": "occupancy grids",
    "fleet.errors": "every exception",
    "fleet.diagnostics": "health levels, watchdog",
}


def unit_graph() -> nx.DiGraph:
    g = nx.DiGraph()
    g.add_nodes_from(SHOWN)
    known = dict(modules())
    for mod, path in known.items():
        a = unit_of(mod)
        if a not in SHOWN:
            continue
        tree = ast.parse(path.read_text())
        for target, _, _ in imports(tree, mod, path.name == "__init__.py"):
            if target not in known:
                continue
            b = unit_of(target)
            if b != a and b in SHOWN:
                g.add_edge(a, b)
    return g


def layers(g: nx.DiGraph) -> list[list[str]]:
    """Rows from top to bottom: the core last; above it, each unit one row above the highest
    unit it imports."""
    core = [u for u in SHOWN if u in CORE]
    rest = g.subgraph([u for u in SHOWN if u not in CORE])
    height: dict[str, int] = {}
    for u in reversed(list(nx.topological_sort(rest))):
        height[u] = 1 + max((height[v] for v in rest.successors(u)), default=0)
    top = max(height.values(), default=0)
    rows: list[list[str]] = [[] for _ in range(top)]
    for u in SHOWN:
        if u in height:
            rows[top - height[u]].append(u)
    return [r for r in rows if r] + [core]


def draw(out: Path) -> None:
    g = unit_graph()
    cyc = list(nx.simple_cycles(g))
    if cyc:
        raise SystemExit(f"import cycles between units: {cyc}")
    red = nx.transitive_reduction(g.subgraph([u for u in SHOWN if u not in CORE]))
    rows = layers(g)
    width = 16.0
    box_w, box_h, gap_y = 2.55, 0.8, 0.55
    pos: dict[str, tuple[float, float]] = {}

    def row_width(n: int) -> float:
        return min(box_w, (width - 0.5 - 0.25 * (n - 1)) / n)

    for r in range(len(rows) - 1, -1, -1):  # bottom up: order a row by where its imports stand
        row = rows[r]
        if r < len(rows) - 1:

            def bary(u: str) -> float:
                xs = [pos[v][0] for v in g.successors(u) if v in pos and v not in CORE]
                return sum(xs) / len(xs) if xs else width / 2

            row.sort(key=bary)
        y = -(r * (box_h + gap_y))
        n = len(row)
        w = row_width(n)
        span = n * w + (n - 1) * 0.25
        x0 = (width - span) / 2
        for i, u in enumerate(row):
            pos[u] = (x0 + i * (w + 0.25) + w / 2, y)
    fig_h = len(rows) * (box_h + gap_y) + 0.6
    fig, ax = plt.subplots(figsize=(width, fig_h))
    ax.set_xlim(0, width)
    ax.set_ylim(-(len(rows) - 1) * (box_h + gap_y) - box_h, box_h)
    ax.axis("off")
    for a, b in red.edges:
        (xa, ya), (xb, yb) = pos[a], pos[b]
        ax.annotate(
            "",
            xy=(xb, yb + box_h / 2),
            xytext=(xa, ya - box_h / 2),
            arrowprops={"arrowstyle": "-|>", "color": "#5a6b7b", "lw": 1.0, "shrinkA": 0, "shrinkB": 0},
        )
    for u, (x, y) in pos.items():
        w = row_width(len(next(row for row in rows if u in row)))
        color = "#f3e3c3" if u in CORE else ("#f4d9de" if u.startswith("sim") else "#d7e6f4")
        ax.add_patch(
            FancyBboxPatch(
                (x - w / 2, y - box_h / 2), w, box_h, boxstyle="round,pad=0.02,rounding_size=0.08",
                facecolor=color, edgecolor="#34495e", lw=1.0,
            )
        )  # fmt: skip
        name = u.replace(".", "/") + ("/" if (ROOT / u.replace(".", "/")).is_dir() else ".py")
        ax.text(x, y + 0.13, name, ha="center", va="center", fontsize=9.5, weight="bold")
        ax.text(x, y - 0.17, SHOWN[u], ha="center", va="center", fontsize=7.5, color="#333")
    ax.set_title(
        "Package layout: each box imports only what stands below it (arrows: direct imports, "
        "implied ones omitted; every box may import the core, bottom row)",
        fontsize=10,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "layout.png")
    args = ap.parse_args(argv)
    assert set(SHOWN) <= set(ALLOWED), sorted(set(SHOWN) - set(ALLOWED))
    draw(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
