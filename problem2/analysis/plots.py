"""Figures of Problem 2's evaluation: episode paths (and the choice of the episodes shown),
the message per grid cell, the channel interventions and an animated episode. Figures use
``matplotlib.figure.Figure`` (no pyplot) and are written atomically. Each static figure is
drawn at the width (inches) at which the report places it (``WIDTHS``), with text of at
least ``MIN_FONT`` points: legible when printed."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from batch_io import temporary_path_for
from grid_maps import OBSTACLE, TARGET
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from rollout import EpisodeResults

from analysis.failures import FAILURE_KINDS, classify_failures

AGENT_COLOURS = ("#1f77b4", "#d62728")  # A blue, B red
AGENT_OFFSETS = (-0.12, 0.12)  # so that the two paths stay apart where they overlap
WIDTHS = {  # inches; report/*.typ places each figure at exactly this width, i.e. at 1:1
    "trajectories": 4.2,
    "message_heatmap": 6.5,
    "strategies": 6.5,
    "interventions": 5.2,
    "measures": 4.3,
    "failure_decomposition": 4.3,
}
MIN_FONT = 9  # points, at print size


# ------------------------------------------------------- the episodes shown
@dataclass
class EpisodeTrace:
    """One recorded episode: positions (L + 1, 2, 2) as (row, col), messages sent (L, 2)."""

    positions: np.ndarray
    messages: np.ndarray
    success: bool
    description: str = ""

    @property
    def length(self) -> int:
        return len(self.messages)


def episode_trace(results: EpisodeResults, index: int, description: str = "") -> EpisodeTrace:
    """Episode ``index`` of recorded ``results``, cut to its length."""
    if results.trajectories is None:
        raise ValueError("episode traces need recorded episodes (record=True)")
    length = int(results.lengths[index])
    return EpisodeTrace(
        positions=results.trajectories["positions"][index, : length + 1],
        messages=results.trajectories["messages"][index, :length],
        success=bool(results.successes[index]),
        description=description,
    )


def representative_success(results: EpisodeResults, label: str) -> EpisodeTrace | None:
    """The first successful episode whose length is the median successful length."""
    successful = np.flatnonzero(results.successes)
    if successful.size == 0:
        return None
    lengths = results.lengths[successful]
    index = successful[np.argmin(np.abs(lengths - np.median(lengths)))]
    return episode_trace(results, int(index), label)


def representative_failure(
    results: EpisodeResults, target: tuple[int, int], label: str
) -> EpisodeTrace | None:
    """The first failed episode of the most common failure kind."""
    kinds = classify_failures(results, target)
    failed = kinds[kinds >= 0]
    if failed.size == 0:
        return None
    common = int(np.bincount(failed, minlength=len(FAILURE_KINDS)).argmax())
    index = int(np.flatnonzero(kinds == common)[0])
    return episode_trace(results, index, f"{FAILURE_KINDS[common]}, {label}")


def longest_success(results: EpisodeResults, label: str) -> EpisodeTrace | None:
    """The first of the longest successful episodes (the hardest start that succeeded)."""
    successful = np.flatnonzero(results.successes)
    if successful.size == 0:
        return None
    index = successful[np.argmax(results.lengths[successful])]
    return episode_trace(results, int(index), f"longest, {label}")


def representative_traces(
    runs: dict[str, EpisodeResults], target: tuple[int, int]
) -> list[EpisodeTrace | None]:
    """[successful, failed] episode, each from the greedy run if it has one, else from the
    ε-greedy run (``runs`` keyed ``greedy`` and ``eps``); where no episode failed, the
    longest successful one instead of the failure; None where neither run has one."""
    order = [(name, "greedy" if name == "greedy" else "ε-greedy") for name in ("greedy", "eps")]
    success = failure = longest = None
    for name, label in order:
        if name in runs:
            success = success or representative_success(runs[name], label)
            failure = failure or representative_failure(runs[name], target, label)
            longest = longest or longest_success(runs[name], label)
    return [success, failure or longest]


FONT_SIZES = {
    "font.size": 10,
    "axes.titlesize": 10,
    "axes.labelsize": 10,
    "xtick.labelsize": MIN_FONT,
    "ytick.labelsize": MIN_FONT,
    "legend.fontsize": MIN_FONT,
    "figure.titlesize": 11,
}


@contextmanager
def legible() -> Iterator[None]:
    """Font sizes for figures printed at their ``WIDTHS``."""
    from matplotlib import rc_context

    with rc_context(FONT_SIZES):
        yield


def draw_map(ax: Axes, grid: np.ndarray, star_size: float = 18) -> None:
    """Obstacles dark grey, the target a gold star, cell grid lines, labelled axes."""
    rows, cols = grid.shape
    ax.imshow(np.where(grid == OBSTACLE, 0.35, 1.0), cmap="gray", vmin=0, vmax=1)
    target_row, target_col = np.argwhere(grid == TARGET)[0]
    ax.plot(target_col, target_row, marker="*", markersize=star_size, color="gold", mec="black")
    ax.vlines(np.arange(-0.5, cols), -0.5, rows - 0.5, color="0.8", linewidth=0.6)
    ax.hlines(np.arange(-0.5, rows), -0.5, cols - 0.5, color="0.8", linewidth=0.6)
    ax.set_xlabel("column")
    ax.set_ylabel("row")


def waiting_steps(trace: EpisodeTrace, target: tuple[int, int]) -> np.ndarray:
    """Steps (2,) each agent spends on the target while its partner is not there yet (the
    positions before each step)."""
    on = (trace.positions[:-1] == np.asarray(target)).all(axis=-1)  # (L, 2)
    return (on & ~on[:, ::-1]).sum(axis=0)


def draw_waiting(ax: Axes, trace: EpisodeTrace, target: tuple[int, int]) -> str:
    """A ring in the waiting agent's colour around the target for each agent that waits
    there for its partner; returns the words for the title ("B waits 9 steps")."""
    words = []
    for agent, steps in enumerate(waiting_steps(trace, target)):
        if steps > 0:
            size = 12 + 4 * agent
            colour, name = AGENT_COLOURS[agent], "AB"[agent]
            ax.plot(target[1], target[0], "o", ms=size, mfc="none", mec=colour, mew=1.8,
                    label=f"{name} waits on the target")  # fmt: skip
            words.append(f"{name} waits {steps} step{'s' if steps != 1 else ''}")
    return ", ".join(words)


def draw_paths(ax: Axes, trace: EpisodeTrace, marker_scale: float = 1.0) -> None:
    """Both agents' paths: a line through the visited cells, a circle at the start and a
    square at the end."""
    for agent in range(2):
        path = trace.positions[:, agent] + AGENT_OFFSETS[agent]
        colour, name = AGENT_COLOURS[agent], "AB"[agent]
        ax.plot(path[:, 1], path[:, 0], color=colour, linewidth=1.6, alpha=0.8)
        start, end = path[0, ::-1], path[-1, ::-1]
        ax.plot(*start, "o", color=colour, markersize=9 * marker_scale, label=f"{name} start")
        ax.plot(*end, "s", color=colour, ms=7 * marker_scale, mfc="none", label=f"{name} end")


def plot_trajectories(
    rows: list[tuple[str, list[EpisodeTrace | None]]],
    grid: np.ndarray,
    path: str | Path,
    messages: list[np.ndarray] | None = None,
) -> Path:
    """One row per mode (label, [successful episode, failed or longest successful episode]);
    None draws an empty panel saying that no such episode occurred. With ``messages`` (one
    mean message per cell (2, H, W) per row), two more columns show what each agent says
    where: the strategy's route and its message in one figure."""
    columns = 2 if messages is None else 4
    width = WIDTHS["trajectories"] if messages is None else WIDTHS["strategies"]
    height = (2.45 if messages is None else 1.75) * len(rows) + 0.9
    with legible():
        fig = Figure(figsize=(width, height), layout="constrained")
        axes = np.atleast_2d(fig.subplots(len(rows), columns))
        _draw_trajectories(fig, axes[:, :2], rows, grid, compact=messages is not None)
        if messages is not None:
            image = None
            for means, row_axes in zip(messages, axes[:, 2:], strict=True):
                for agent, ax in enumerate(row_axes):
                    image = draw_message_map(ax, grid, means[agent])
                    ax.set_title(f"message sent by {'AB'[agent]}", fontsize=MIN_FONT)
            label = "mean message sent (greedy episodes)"
            fig.colorbar(image, ax=axes[:, 2:], shrink=0.6, label=label)
            for ax in axes[:, 1:].flat:
                ax.set_ylabel("")
                ax.set_yticklabels([])
            for ax in axes[:-1].flat:
                ax.set_xlabel("")
                ax.set_xticklabels([])
        return save_figure(fig, path, dpi=200 if messages is not None else 120)


def _draw_trajectories(
    fig: Figure,
    axes: np.ndarray,
    rows: list[tuple[str, list[EpisodeTrace | None]]],
    grid: np.ndarray,
    compact: bool = False,
) -> None:
    target = tuple(np.argwhere(grid == TARGET)[0])
    for (label, traces), row_axes in zip(rows, axes, strict=True):
        for ax, trace, kind in zip(row_axes, traces, ("successful", "other"), strict=True):
            draw_map(ax, grid, star_size=11 if compact else 18)
            ax.set_xticks(range(0, grid.shape[1], 2))
            ax.set_yticks(range(0, grid.shape[0], 2))
            head = "" if compact else f"{label}:\n"
            if trace is None:
                ax.set_title(f"{head}no {kind} episode", fontsize=MIN_FONT)
                continue
            draw_paths(ax, trace, marker_scale=0.7 if compact else 1.0)
            waits = draw_waiting(ax, trace, target)
            steps = f"{trace.length} step{'s' if trace.length != 1 else ''}"
            outcome = f"success in {steps}" if trace.success else "failure"
            details = [w for w in (trace.description, waits) if w]  # the kind, who waits
            if compact:  # one line each
                ax.set_title("\n".join([outcome, *details]), fontsize=MIN_FONT)
            else:
                detail = f" ({'; '.join(details)})" if details else ""
                ax.set_title(f"{head}{outcome}{detail}", fontsize=MIN_FONT)
        if compact:
            row_axes[0].set_ylabel(f"{label}\nrow")
    handles = {}  # every panel's entries once (a ring only where an agent waits)
    for ax in axes.flat:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=3)
    if compact:
        fig.suptitle("Representative episodes and the messages sent from each cell (best seed)")
    else:
        fig.suptitle("Representative episodes\n(A blue, B red; star: target; grey: obstacles)")


def draw_message_map(ax: Axes, grid: np.ndarray, means: np.ndarray):
    """The mean message an agent sent from each cell (H, W): viridis from 0 to 1, cells it
    never sent from light grey, obstacles dark grey, the target a white star."""
    values = np.ma.masked_invalid(np.where(grid == OBSTACLE, np.nan, means))
    image = ax.imshow(values, cmap=_viridis_with_grey(), vmin=0, vmax=1)
    ax.imshow(np.ma.masked_where(grid != OBSTACLE, grid), cmap="gray", vmin=0, vmax=2)
    target_row, target_col = np.argwhere(grid == TARGET)[0]
    ax.plot(target_col, target_row, marker="*", markersize=11, mfc="none", mec="white")
    ax.set_xticks(range(0, grid.shape[1], 2))
    ax.set_yticks(range(0, grid.shape[0], 2))
    ax.set_xlabel("column")
    ax.set_ylabel("row")
    return image


def plot_message_heatmap(
    panels: list[tuple[str, np.ndarray]], grid: np.ndarray, path: str | Path
) -> Path:
    """One row per (label, mean message (2, H, W)); columns agent A and agent B. Cells an
    agent never sent from are light grey, obstacles dark grey, the target a white star."""
    with legible():
        fig = Figure(
            figsize=(WIDTHS["message_heatmap"], 3.0 * len(panels) + 0.9), layout="constrained"
        )
        axes = np.atleast_2d(fig.subplots(len(panels), 2))
        image = None
        for (label, means), row_axes in zip(panels, axes, strict=True):
            for agent, ax in enumerate(row_axes):
                image = draw_message_map(ax, grid, means[agent])
                ax.set_title(f"{label}: sent by {'AB'[agent]}")
        if image is not None:
            fig.colorbar(image, ax=axes, shrink=0.8, label="mean message sent (0 to 1)")
        fig.suptitle("Mean message sent from each cell (greedy test episodes, best seed)")
        fig.supxlabel("white star: target; dark grey: obstacle; light grey: never visited")
        return save_figure(fig, path, dpi=200)


def plot_interventions(modes: dict[str, dict], path: str | Path) -> Path:
    """Δsuccess (intervention − real) with its 95 % CI over seeds, one panel per mode and
    channel (``modes``: mode -> channel -> the ``interventions`` entry), greedy and
    ε-greedy side by side."""
    panels = [(mode, channel, entry) for mode, channels in modes.items()
              for channel, entry in channels.items()]  # fmt: skip
    with legible():
        fig = Figure(
            figsize=(WIDTHS["interventions"], 1.3 * len(panels) + 0.9), layout="constrained"
        )
        axes = np.atleast_1d(fig.subplots(len(panels), 1, squeeze=False, sharex=True)[:, 0])
        for ax, (mode, channel, entry) in zip(axes, panels, strict=True):
            kinds = list(entry["greedy"]["delta_success"])
            rows = np.arange(len(kinds))
            for offset, (condition, colour) in zip(
                (-0.2, 0.2), (("greedy", "#4c72b0"), ("eps", "#dd8452")), strict=True
            ):
                stats = [entry[condition]["delta_success"][k] for k in kinds]
                means = 100 * np.array([s["mean"] for s in stats])  # percentage points
                lows = 100 * np.array([s["ci95"][0] for s in stats])
                highs = 100 * np.array([s["ci95"][1] for s in stats])
                label = "greedy" if condition == "greedy" else "ε = 0.05"
                ax.barh(rows + offset, means, height=0.38, color=colour, label=label,
                        xerr=[means - lows, highs - means], capsize=2)  # fmt: skip
            ax.axvline(0, color="black", linewidth=0.8)
            ax.set_yticks(rows, [k.replace("_", " ") for k in kinds])
            ax.invert_yaxis()
            verdict = entry["eps"]["verdict"]
            ax.set_title(f"{mode}: {channel} (verdict at ε = 0.05: {verdict})")
        axes[-1].set_xlabel("Δ success vs the real input (points; 95 % CI over seeds)")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=2)
        fig.suptitle("What happens when an input channel is replaced")
        return save_figure(fig, path, dpi=200)


def plot_measures(modes: dict[str, dict], bins: str, path: str | Path) -> Path:
    """Each communication measure (``modes``: mode -> {"K2": {measure: {sender: seed
    statistics}}}) per mode, senders A and B, mean with its 95 % CI over seeds."""
    measures = list(next(iter(modes.values()))[bins])
    with legible():
        fig = Figure(figsize=(WIDTHS["measures"], 0.95 * len(measures) + 1.2), layout="constrained")
        axes = fig.subplots(len(measures), 1, squeeze=False)[:, 0]
        rows = np.arange(len(modes))
        for ax, measure in zip(axes, measures, strict=True):
            for offset, sender in zip((-0.2, 0.2), "AB", strict=True):
                stats = [modes[mode][bins][measure][sender] for mode in modes]
                means = np.array([s["mean"] for s in stats])
                errors = np.array(
                    [
                        [m - s["ci95"][0], s["ci95"][1] - m]
                        for m, s in zip(means, stats, strict=True)
                    ]
                ).T
                colour = AGENT_COLOURS["AB".index(sender)]
                ax.barh(rows + offset, means, height=0.38, xerr=np.maximum(errors, 0),
                        capsize=2, color=colour, label=f"sender {sender}")  # fmt: skip
            ax.set_yticks(rows, list(modes))
            ax.invert_yaxis()
            ax.set_title(measure.replace("_", " "))
        axes[-1].set_xlabel(f"bits (message in {bins[1:]} bins; 95 % CI over seeds)")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=2)
        fig.suptitle("Communication measures (Lowe et al. 2019),\ngreedy test episodes")
        return save_figure(fig, path, dpi=200)


def plot_failure_decomposition(modes: dict[str, dict], path: str | Path) -> Path:
    """Share of test episodes that fail by navigation (an agent never reached the target)
    and by timing (both did, never together), per mode and condition (``modes``: mode ->
    the performance entry)."""
    labels, navigation, timing = [], [], []
    for mode, entry in modes.items():
        for condition in ("greedy", "eps"):
            failed = 1 - np.array(entry[condition]["success_rate"]["per_seed"])
            shares = entry[condition]["failure_decomposition"]
            labels.append(f"{mode}, {'greedy' if condition == 'greedy' else 'ε-greedy'}")
            for kind, bars in (("navigation", navigation), ("timing", timing)):
                per_seed = [0.0 if v is None else v for v in shares[kind]["per_seed"]]
                bars.append(float(np.mean(failed * np.array(per_seed))))  # share of all episodes
    with legible():
        fig = Figure(
            figsize=(WIDTHS["failure_decomposition"], 0.25 * len(labels) + 1.6),
            layout="constrained",
        )
        ax = fig.subplots()
        rows = np.arange(len(labels))
        ax.barh(rows, navigation, color="#8172b3", label="navigation: an agent never reached it")
        ax.barh(rows, timing, left=navigation, color="#ccb974",
                label="timing: both reached it, never together")  # fmt: skip
        ax.set_yticks(rows, labels)
        ax.invert_yaxis()
        ax.set_xlabel("share of test episodes that fail\n(mean over seeds)")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=1)
        fig.suptitle("Why episodes fail")
        return save_figure(fig, path, dpi=200)


def _viridis_with_grey():
    from matplotlib import colormaps

    return colormaps["viridis"].with_extremes(bad="0.88")


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


def save_figure(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically."""
    with temporary_path_for(path) as temporary:
        fig.savefig(temporary, format="png", dpi=dpi)
    return Path(path)
