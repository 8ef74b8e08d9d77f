"""A picture of a run: the map, the roadmap, chargers, stations and every robot's trajectory.

Uses matplotlib's non-interactive Agg backend (no display needed). Map frame, meters.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from fleet.maps import OccupancyGrid

Trajectory = Sequence[tuple[float, float, float]]


def plot_run(
    config: FleetConfig,
    trajectories: Mapping[str, Trajectory],
    path: str | Path,
    *,
    title: str = "",
    collisions: Sequence[tuple[float, float]] = (),
    dpi: int = 120,
) -> Path:
    """Draw the run and save it as PNG to ``path`` (parent folders are created).

    ``trajectories`` maps robot names to ``(t, x, y)`` samples (s, m, m); each robot gets its
    own color, a circle at its start and a square at its end. ``collisions`` are ``(x, y)``
    points marked with a red cross. Returns the path written.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    grid = config.grid
    xmin, xmax, ymin, ymax = grid.extent
    aspect = (ymax - ymin) / max(xmax - xmin, 1e-9)
    width = 11.0
    fig, ax = plt.subplots(figsize=(width, max(4.0, width * aspect * 0.8 + 1.0)))
    try:
        draw_map(ax, config, edge_lw=0.6)
        rm = config.roadmap
        if len(rm):
            pts = np.array([rm.pos(n) for n in rm.nodes])
            ax.scatter(pts[:, 0], pts[:, 1], s=4, color="#789", zorder=1)
        if config.stations:
            st = np.array([(s.pose.x, s.pose.y) for s in config.stations.values()])
            ax.scatter(st[:, 0], st[:, 1], marker="^", s=14, color="#c80", label="stations", zorder=2)
        if config.chargers:
            ch = np.array([(c.pose.x, c.pose.y) for c in config.chargers])
            ax.scatter(
                ch[:, 0], ch[:, 1], marker="P", s=90, color="#2a2", edgecolor="k", label="chargers", zorder=3
            )
        cmap = plt.get_cmap("tab20" if len(trajectories) > 10 else "tab10")
        many = len(trajectories) > 20
        for i, (name, traj) in enumerate(trajectories.items()):
            if not traj:
                continue
            xy = np.array([(x, y) for _, x, y in traj])
            color = cmap(i % cmap.N)
            ax.plot(
                xy[:, 0], xy[:, 1], color=color, lw=1.0, alpha=0.85, label=None if many else name, zorder=4
            )
            ax.scatter([xy[0, 0]], [xy[0, 1]], marker="o", s=25, color=color, edgecolor="k", zorder=5)
            ax.scatter([xy[-1, 0]], [xy[-1, 1]], marker="s", s=25, color=color, edgecolor="k", zorder=5)
        if collisions:
            c = np.array(collisions)
            ax.scatter(c[:, 0], c[:, 1], marker="x", s=60, color="red", label="collisions", zorder=6)
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, map frame)")
        ax.set_ylabel("y (m)")
        ax.set_title(title or config.name)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="o start, ■ end")
        fig.tight_layout()
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi)
    finally:
        plt.close(fig)
    return out


def draw_map(ax: Any, config: FleetConfig, *, edge_lw: float = 0.6) -> None:
    """Draw the occupancy map (free light, occupied dark, in the ``map`` frame, meters) and the
    roadmap edges on the matplotlib axes ``ax``, below anything drawn later."""
    grid = config.grid
    xmin, xmax, ymin, ymax = grid.extent
    ax.imshow(
        _map_image(grid),
        origin="lower",
        extent=(xmin, xmax, ymin, ymax),
        cmap="gray",
        vmin=0,
        vmax=255,
        zorder=0,
    )
    rm = config.roadmap
    for a, b in rm.edges:
        (x0, y0), (x1, y1) = rm.pos(a), rm.pos(b)
        ax.plot([x0, x1], [y0, y1], color="#9ab", lw=edge_lw, zorder=1)


def _map_image(grid: OccupancyGrid) -> np.ndarray:
    """Grey levels (rows bottom-up): free light grey, occupied dark grey, unknown mid grey."""
    from fleet.maps import FREE, OCCUPIED

    img = np.full(grid.cells.shape, 160, dtype=np.uint8)
    img[grid.cells == FREE] = 235
    img[grid.cells == OCCUPIED] = 90
    return img
