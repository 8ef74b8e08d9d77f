"""The three pictures of a load test (:mod:`fleet.loadtest`), drawn with matplotlib's Agg backend.

* :func:`plot_throughput`: laps per robot-hour over simulated time (cumulative average and a
  sliding window), with cumulative laps on a second axis;
* :func:`plot_states`: stacked area of robots per state over simulated time, plus the number
  of waiting robots;
* :func:`plot_congestion`: heat map of where robots waited, over the warehouse map.

Inputs are the ``loadtest.series`` dict of the report (lists, one entry per sample; time in
simulated seconds). Every function creates the parent folder and returns the path written.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig

#: Colors of the robot states (stable across plots).
STATE_COLORS = {
    "patrol": "#2c7bb6",
    "picking": "#7b3294",
    "recovery": "#fdae61",
    "charging": "#1a9641",
    "idle": "#bdbdbd",
    "stuck": "#d7191c",
    "dead": "#252525",
}


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: str | Path, dpi: int) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


def _minutes(t: list[float]) -> tuple[np.ndarray, str]:
    arr = np.asarray(t, dtype=float)
    if len(arr) and arr[-1] > 600:
        return arr / 60.0, "simulated time (min)"
    return arr, "simulated time (s)"


def plot_throughput(series: Mapping[str, Any], path: str | Path, *, title: str = "", dpi: int = 100) -> Path:
    """Laps per robot-hour over time: cumulative average (thick) and over the last 60 s (thin),
    and cumulative laps (right axis, dashed)."""
    plt = _plt()
    t, xlabel = _minutes(series["t_s"])
    fig, ax = plt.subplots(figsize=(8, 4.2))
    try:
        ax.plot(
            t, series["throughput_window_laps_per_robot_hour"], color="#9ecae1", lw=1.2, label="last 60 s"
        )
        ax.plot(t, series["throughput_laps_per_robot_hour"], color="#08519c", lw=2.2, label="since start")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("laps per robot-hour")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax2 = ax.twinx()
        ax2.plot(t, series["laps"], color="#e6550d", lw=1.4, ls="--", label="laps completed (right)")
        ax2.set_ylabel("laps completed", color="#e6550d")
        ax2.tick_params(axis="y", colors="#e6550d")
        ax2.set_ylim(bottom=0)
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, loc="upper left", fontsize=8)
        ax.set_title(f"Throughput: {title}" if title else "Throughput", fontsize=10)
        fig.tight_layout()
        return _save(fig, path, dpi)
    finally:
        plt.close(fig)


def plot_states(series: Mapping[str, Any], path: str | Path, *, title: str = "", dpi: int = 100) -> Path:
    """Stacked area of robots per state over time; the black line is the number of robots
    waiting (driving mode but slower than 0.1 m/s, or stuck)."""

    plt = _plt()
    t, xlabel = _minutes(series["t_s"])
    states = series["states"]
    shown = [s for s in states if any(states[s])]  # the series' own order
    fig, ax = plt.subplots(figsize=(8, 4.2))
    try:
        if shown and len(t):
            ax.stackplot(
                t,
                *[np.asarray(states[s], dtype=float) for s in shown],
                labels=shown,
                colors=[STATE_COLORS[s] for s in shown],
                alpha=0.9,
            )
        ax.plot(t, series["waiting"], color="k", lw=1.2, label="waiting")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("robots")
        ax.set_ylim(bottom=0)
        if len(t):
            ax.set_xlim(t[0], t[-1] if t[-1] > t[0] else t[0] + 1)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        ax.set_title(f"Robot states: {title}" if title else "Robot states", fontsize=10)
        fig.tight_layout()
        return _save(fig, path, dpi)
    finally:
        plt.close(fig)


def plot_congestion(
    config: FleetConfig,
    heat: np.ndarray,
    path: str | Path,
    *,
    bin_m: float = 1.0,
    title: str = "",
    dpi: int = 100,
) -> Path:
    """Heat map of ``heat`` (robot-samples waiting per ``bin_m`` cell, rows bottom-up from the
    map's lower-left corner) over the map (shelves and walls dark) and its roadmap."""
    from matplotlib.colors import LogNorm

    from fleet.viz.plot import draw_map

    plt = _plt()
    grid = config.grid
    xmin, xmax, ymin, ymax = grid.extent
    aspect = (ymax - ymin) / max(xmax - xmin, 1e-9)
    width = 10.0
    fig, ax = plt.subplots(figsize=(width, min(12.0, max(3.5, width * aspect * 0.85 + 1.2))))
    try:
        draw_map(ax, config, edge_lw=0.4)
        h = np.asarray(heat, dtype=float)
        ny, nx = h.shape
        ext = (xmin, xmin + nx * bin_m, ymin, ymin + ny * bin_m)
        total = int(h.sum())
        if total > 0:
            masked = np.ma.masked_less_equal(h, 0)
            im = ax.imshow(
                masked,
                origin="lower",
                extent=ext,
                cmap="inferno_r",
                alpha=0.85,
                zorder=2,
                norm=LogNorm(vmin=1, vmax=max(2.0, float(h.max()))),
                interpolation="nearest",
            )
            cb = fig.colorbar(im, ax=ax, fraction=0.035, pad=0.02)
            cb.set_label(f"waiting robot-samples per {bin_m:g} m cell")
        else:
            ax.text(
                0.5,
                0.5,
                "no waiting robots sampled",
                transform=ax.transAxes,
                ha="center",
                va="center",
                fontsize=12,
                color="#333",
                bbox={"fc": "white", "alpha": 0.8},
            )
        if config.chargers:
            ch = np.array([(c.pose.x, c.pose.y) for c in config.chargers])
            ax.scatter(
                ch[:, 0],
                ch[:, 1],
                marker="P",
                s=30,
                color="#2a2",
                edgecolor="k",
                lw=0.4,
                label="chargers",
                zorder=3,
            )
            ax.legend(loc="upper right", fontsize=8)
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, map frame)")
        ax.set_ylabel("y (m)")
        head = f"Congestion ({total} waiting robot-samples)"
        ax.set_title(f"{head}: {title}" if title else head, fontsize=10)
        fig.tight_layout()
        return _save(fig, path, dpi)
    finally:
        plt.close(fig)


__all__ = ["STATE_COLORS", "plot_congestion", "plot_states", "plot_throughput"]
