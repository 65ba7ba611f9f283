"""Figures of Problem 2's evaluation: episode paths, the message per grid cell and an
animated episode. Figures use ``matplotlib.figure.Figure`` (no pyplot) and are written
atomically."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from _atomic import temporary_path_for
from analysis_traces import EpisodeTrace
from grid_maps import OBSTACLE, TARGET
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.axes import Axes
from matplotlib.figure import Figure

AGENT_COLOURS = ("#1f77b4", "#d62728")  # A blue, B red
AGENT_OFFSETS = (-0.12, 0.12)  # so that the two paths stay apart where they overlap


def draw_map(ax: Axes, grid: np.ndarray) -> None:
    """Obstacles dark grey, the target a gold star, cell grid lines, labelled axes."""
    rows, cols = grid.shape
    ax.imshow(np.where(grid == OBSTACLE, 0.35, 1.0), cmap="gray", vmin=0, vmax=1)
    target_row, target_col = np.argwhere(grid == TARGET)[0]
    ax.plot(target_col, target_row, marker="*", markersize=18, color="gold", mec="black")
    ax.set_xticks(np.arange(-0.5, cols), minor=True)
    ax.set_yticks(np.arange(-0.5, rows), minor=True)
    ax.grid(which="minor", color="0.8", linewidth=0.6)
    ax.tick_params(which="minor", length=0)
    ax.set_xlabel("column")
    ax.set_ylabel("row")


def draw_paths(ax: Axes, trace: EpisodeTrace) -> None:
    """Both agents' paths: a line through the visited cells, a circle at the start and a
    square at the end."""
    for agent in range(2):
        path = trace.positions[:, agent] + AGENT_OFFSETS[agent]
        colour, name = AGENT_COLOURS[agent], "AB"[agent]
        ax.plot(path[:, 1], path[:, 0], color=colour, linewidth=1.6, alpha=0.8)
        ax.plot(*path[0, ::-1], "o", color=colour, markersize=9, label=f"{name} start")
        ax.plot(*path[-1, ::-1], "s", color=colour, markersize=7, mfc="none", label=f"{name} end")


def plot_trajectories(
    rows: list[tuple[str, list[EpisodeTrace | None]]], grid: np.ndarray, path: str | Path
) -> Path:
    """One row per mode (label, [successful episode, failed episode]); None draws an empty
    panel saying that no such episode occurred."""
    fig = Figure(figsize=(9, 4.3 * len(rows)), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(rows), 2))
    for (label, traces), row_axes in zip(rows, axes, strict=True):
        for ax, trace, kind in zip(row_axes, traces, ("successful", "failed"), strict=True):
            draw_map(ax, grid)
            if trace is None:
                ax.set_title(f"{label}: no {kind} episode")
                continue
            draw_paths(ax, trace)
            outcome = f"success in {trace.length} steps" if trace.success else "failure"
            detail = f" ({trace.description})" if trace.description else ""
            ax.set_title(f"{label}: {outcome}{detail}", fontsize=10)
    axes[0, 0].legend(loc="upper left", bbox_to_anchor=(0, -0.12), ncol=4, fontsize=8)
    fig.suptitle("Representative episodes (A blue, B red; ★ target, grey obstacles)")
    return save_figure(fig, path)


def plot_message_heatmap(
    panels: list[tuple[str, np.ndarray]], grid: np.ndarray, path: str | Path
) -> Path:
    """One row per (label, mean message (2, H, W)); columns agent A and agent B. Cells an
    agent never sent from are light grey, obstacles dark grey."""
    fig = Figure(figsize=(9, 4 * len(panels)), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(panels), 2))
    image = None
    for (label, means), row_axes in zip(panels, axes, strict=True):
        for agent, ax in enumerate(row_axes):
            values = np.ma.masked_invalid(np.where(grid == OBSTACLE, np.nan, means[agent]))
            cmap = _viridis_with_grey()
            image = ax.imshow(values, cmap=cmap, vmin=0, vmax=1)
            ax.imshow(np.ma.masked_where(grid != OBSTACLE, grid), cmap="gray", vmin=0, vmax=2)
            target_row, target_col = np.argwhere(grid == TARGET)[0]
            ax.plot(target_col, target_row, marker="*", markersize=16, mfc="none", mec="white")
            ax.set_title(f"{label}: message sent by agent {'AB'[agent]}", fontsize=10)
            ax.set_xlabel("column")
            ax.set_ylabel("row")
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.8, label="mean message sent from the cell (0–1)")
    fig.suptitle("Mean message per cell (greedy test episodes, best seed; ☆ target)")
    return save_figure(fig, path)


def _viridis_with_grey():
    from matplotlib import colormaps

    cmap = colormaps["viridis"].copy()
    cmap.set_bad("0.88")
    return cmap


def save_episode_gif(
    trace: EpisodeTrace, grid: np.ndarray, path: str | Path, title: str, fps: int = 3
) -> Path:
    """Animate one episode: both agents on the map (left) and the message each sends at
    that step (right), one frame per step plus the final position."""
    fig = Figure(figsize=(7.5, 4.2), layout="constrained")
    map_ax, bar_ax = fig.subplots(1, 2, width_ratios=(2.2, 1))
    draw_map(map_ax, grid)
    markers = [
        map_ax.plot([], [], "o", color=AGENT_COLOURS[a], markersize=14, label=f"agent {'AB'[a]}")[0]
        for a in range(2)
    ]
    trails = [map_ax.plot([], [], color=AGENT_COLOURS[a], alpha=0.5)[0] for a in range(2)]
    map_ax.legend(loc="upper left", bbox_to_anchor=(0, -0.12), ncol=2, fontsize=8)
    bars = bar_ax.bar(["A → B", "B → A"], [0, 0], color=AGENT_COLOURS)
    bar_ax.set_ylim(0, 1)
    bar_ax.set_ylabel("message sent at this step (0–1)")
    bar_ax.set_title("messages")
    heading = fig.suptitle(title)

    def draw(frame: int) -> list:
        for agent in range(2):
            path = trace.positions[: frame + 1, agent] + AGENT_OFFSETS[agent]
            markers[agent].set_data([path[-1, 1]], [path[-1, 0]])
            trails[agent].set_data(path[:, 1], path[:, 0])
        sent = trace.messages[min(frame, trace.length - 1)]
        for bar, value in zip(bars, sent, strict=True):
            bar.set_height(float(value))
        status = "both on the target" if frame == trace.length and trace.success else ""
        heading.set_text(f"{title} — step {frame}/{trace.length} {status}".rstrip())
        return [*markers, *trails, *bars, heading]

    animation = FuncAnimation(fig, draw, frames=trace.length + 1, blit=False)
    final = Path(path)
    with temporary_path_for(final) as temporary:
        # Pillow picks the format from the file name's suffix, so write a *.gif first.
        staged = temporary.with_name(temporary.name + ".gif")
        try:
            animation.save(staged, writer=PillowWriter(fps=fps), dpi=72)
            os.replace(staged, temporary)
        finally:
            staged.unlink(missing_ok=True)
    return final


def save_figure(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically."""
    with temporary_path_for(path) as temporary:
        fig.savefig(temporary, format="png", dpi=dpi)
    return Path(path)
