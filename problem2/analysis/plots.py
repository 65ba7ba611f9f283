"""Figures of Problem 2's evaluation: episode paths (and the choice of the episodes shown) and
the message per grid cell (the estimates with intervals are in :mod:`analysis.estimate_plots`,
an animated episode in :mod:`analysis.animation`). Figures use
``matplotlib.figure.Figure`` (no pyplot) and are written atomically. Each static figure is
drawn at the width (inches) at which the report places it (``WIDTHS``), with text of at
least ``MIN_FONT`` points: legible when printed."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from safety import temporary_path_for

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, StrMethodFormatter
from rollout import EpisodeResults
from vector_env import MASKED_INPUTS, MESSAGE_INDEX, OBSTACLE, TARGET

from analysis.failures import FAILURE_KINDS, classify_failures
from analysis.messages import mean_message_per_cell

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


def strategy_rows(
    runs: dict[str, dict[str, EpisodeResults]], experiment: dict
) -> tuple[list[tuple[str, list[EpisodeTrace | None]]], list[np.ndarray]]:
    """The rows of ``trajectories.png`` (:func:`plot_trajectories`) and the mean message
    per cell of each, from ``runs[mode]`` (the greedy and ε-greedy episodes of the mode's
    best seed) and ``experiment`` (its entry in performance.json: grid, target, modes)."""
    shape, target = np.shape(experiment["grid"]), tuple(experiment["target"])
    rows, messages = [], []
    for mode, mode_runs in runs.items():
        label = f"{mode} (seed {experiment['modes'][mode]['best_seed']})"
        rows.append((label, representative_traces(mode_runs, target)))
        messages.append(mean_message_per_cell(mode_runs["greedy"], shape))
    return rows, messages


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


def draw_waiting(ax: Axes, trace: EpisodeTrace, target: tuple[int, int]) -> list[str]:
    """A ring in the waiting agent's colour around the target for each agent that waits
    there for its partner; returns the words for the title, one per agent that waits
    ("B waits 9 steps")."""
    words = []
    for agent, steps in enumerate(waiting_steps(trace, target)):
        if steps > 0:
            size = 12 + 4 * agent
            colour, name = AGENT_COLOURS[agent], "AB"[agent]
            ax.plot(
                target[1],
                target[0],
                "o",
                ms=size,
                mfc="none",
                mec=colour,
                mew=1.8,
                label=f"{name} waits on the target",
            )
            words.append(f"{name} waits {steps} step{'s' if steps != 1 else ''}")
    return words


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
    where, every row on one colour scale from 0 to 1: the strategy's route and its message
    in one figure."""
    columns = 2 if messages is None else 4
    width = WIDTHS["trajectories"] if messages is None else WIDTHS["strategies"]
    height = (2.45 if messages is None else 2.1) * len(rows) + 1.0
    with legible():
        fig = Figure(figsize=(width, height), layout="constrained")
        axes = np.atleast_2d(fig.subplots(len(rows), columns))
        _draw_trajectories(fig, axes[:, :2], rows, grid, compact=messages is not None)
        if messages is not None:
            fig.get_layout_engine().set(h_pad=0.08, hspace=0.06)  # titles clear of the row above
            image = None
            for (label, _), means, row_axes in zip(rows, messages, axes[:, 2:], strict=True):
                if MESSAGE_INDEX in MASKED_INPUTS.get(label.split(" (")[0], ()):  # no listener
                    for ax in row_axes:
                        ax.set_axis_off()
                    row_axes[0].text(
                        1.0,
                        0.5,
                        f"{label.split(' (')[0]} agents hear no message:\nno message map",
                        transform=row_axes[0].transAxes,
                        ha="center",
                        va="center",
                        fontsize=MIN_FONT,
                    ).set_in_layout(False)  # the empty row keeps the layout of the others
                    continue
                for agent, ax in enumerate(row_axes):
                    image = draw_message_map(ax, grid, means[agent])
                    ax.set_title(f"message sent by {'AB'[agent]}", fontsize=MIN_FONT)
            # One scale, the channel's whole range, for every row: rows compare directly.
            bar = fig.colorbar(image, ax=axes[:, 2:], shrink=0.5, aspect=20)
            bar.set_label("mean message", fontsize=MIN_FONT)
            for ax in axes[:, 1:].flat:
                ax.set_ylabel("")
                ax.set_yticklabels([])
            for ax in axes[:-1].flat:
                ax.set_xlabel("")
                ax.set_xticklabels([])
        return save_figure(fig, path, dpi=200 if messages is not None else 120)


def draw_message_row(
    fig: Figure, row_axes: np.ndarray, grid: np.ndarray, means: np.ndarray, titles: list[str]
) -> None:
    """Both agents' message maps (``means`` (2, H, W)) on ``row_axes``, coloured over the
    row's range (:func:`message_range`), with the row's colour bar and its values."""
    low, high = message_range(means)
    for agent, ax in enumerate(row_axes):
        image = draw_message_map(ax, grid, means[agent], low, high)
        ax.set_title(titles[agent], fontsize=MIN_FONT)
    bar = fig.colorbar(image, ax=row_axes, shrink=0.85, aspect=12)
    bar.ax.yaxis.set_major_locator(MaxNLocator(4))
    digits = max(2, int(np.ceil(-np.log10(high - low))) + 1)  # ticks that differ when printed
    bar.ax.yaxis.set_major_formatter(StrMethodFormatter(f"{{x:.{digits}f}}"))
    bar.set_label("mean message", fontsize=MIN_FONT)


def message_range(means: np.ndarray) -> tuple[float, float]:
    """The colour scale of a row's message maps: the range of the mean messages (2, H, W)
    it shows, at least 0.001 wide (a constant message gets a scale around its value)."""
    finite = means[np.isfinite(means)]
    if finite.size == 0:
        return 0.0, 1.0
    low, high = float(finite.min()), float(finite.max())
    pad = max(0.0, 0.001 - (high - low)) / 2
    return low - pad, high + pad


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
            details = [w for w in (trace.description, *waits) if w]  # the kind, who waits
            if compact:  # one short line each: the titles of neighbouring panels stay apart
                short = f"success, {steps}" if trace.success else "failure"
                ax.set_title("\n".join([short, *details]), fontsize=MIN_FONT)
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
    firsts = [traces[0] for _, traces in rows if traces[0] is not None]
    same_start = len(firsts) > 1 and all(
        np.array_equal(t.positions[0], firsts[0].positions[0]) for t in firsts
    )  # the test episodes of every mode start from the same cells
    if compact:
        fig.suptitle(
            "Representative episodes and the messages sent from each cell (best seed)"
            + (
                "\nfirst column: the same test episode (start cells) in every row"
                if same_start
                else ""
            )
        )
    else:
        fig.suptitle("Representative episodes\n(A blue, B red; star: target; grey: obstacles)")


def draw_message_map(
    ax: Axes, grid: np.ndarray, means: np.ndarray, low: float = 0.0, high: float = 1.0
):
    """The mean message an agent sent from each cell (H, W): viridis from ``low`` to
    ``high``, cells it never sent from light grey, obstacles dark grey, the target a white
    star."""
    values = np.ma.masked_invalid(np.where(grid == OBSTACLE, np.nan, means))
    image = ax.imshow(values, cmap=_viridis_with_grey(), vmin=low, vmax=high)
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
    """One row per (label, mean message (2, H, W)); columns agent A and agent B, each row
    on its own colour scale (its bar beside it). Cells an agent never sent from are light
    grey, obstacles dark grey, the target a white star."""
    with legible():
        fig = Figure(
            figsize=(WIDTHS["message_heatmap"], 3.0 * len(panels) + 0.9), layout="constrained"
        )
        axes = np.atleast_2d(fig.subplots(len(panels), 2))
        for (label, means), row_axes in zip(panels, axes, strict=True):
            titles = [f"{label}: sent by {agent}" for agent in "AB"]
            draw_message_row(fig, row_axes, grid, means, titles)
        fig.suptitle("Mean message sent from each cell (greedy test episodes, best seed)")
        fig.supxlabel("white star: target; dark grey: obstacle; light grey: never visited")
        return save_figure(fig, path, dpi=200)


def _viridis_with_grey():
    from matplotlib import colormaps

    return colormaps["viridis"].with_extremes(bad="0.88")


def save_figure(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically."""
    with temporary_path_for(path) as temporary:
        fig.savefig(temporary, format="png", dpi=dpi)
    return Path(path)
