"""An animated episode of Problem 2 (``episode_<mode>.gif`` of ``python -m
analysis.pipeline``): both agents on the map with their trails and the messages they send."""

from __future__ import annotations

import os
from pathlib import Path

from safety import temporary_path_for

import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.figure import Figure

from analysis.plots import AGENT_COLOURS, AGENT_OFFSETS, EpisodeTrace, draw_map


def save_episode_gif(
    trace: EpisodeTrace, grid: np.ndarray, path: str | Path, title: str, fps: int = 3
) -> Path:
    """Animate one episode: both agents on the map with their trails, and the message each
    sends at that step written beside it, one frame per step plus the final position."""
    fig = Figure(figsize=(5.2, 5.4))
    ax = fig.add_axes((0.12, 0.13, 0.8, 0.76))  # fixed layout: fast frames
    draw_map(ax, grid)
    markers, trails, labels = [], [], []
    for agent in range(2):
        colour = AGENT_COLOURS[agent]
        markers.append(ax.plot([], [], "o", color=colour, markersize=13)[0])
        trails.append(ax.plot([], [], color=colour, alpha=0.5)[0])
        labels.append(ax.text(0, 0, "", color=colour, fontsize=9, fontweight="bold"))
    caption = fig.text(0.5, 0.02, "", ha="center", fontsize=9)
    heading = fig.suptitle(title)

    def draw(frame: int) -> list:
        sent = trace.messages[min(frame, trace.length - 1)]
        for agent in range(2):
            path = trace.positions[: frame + 1, agent] + AGENT_OFFSETS[agent]
            markers[agent].set_data([path[-1, 1]], [path[-1, 0]])
            trails[agent].set_data(path[:, 1], path[:, 0])
            labels[agent].set_position((path[-1, 1] + 0.25, path[-1, 0] - 0.25 + 0.5 * agent))
            labels[agent].set_text(f"{sent[agent]:.2f}")
        caption.set_text(
            f"messages sent (0–1): A (blue) → B {sent[0]:.2f}, B (red) → A {sent[1]:.2f}"
            if frame < trace.length
            else "episode over"
        )
        done = " — both on the target" if frame == trace.length and trace.success else ""
        heading.set_text(f"{title}: step {frame}/{trace.length}{done}")
        return [*markers, *trails, *labels, caption, heading]

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
