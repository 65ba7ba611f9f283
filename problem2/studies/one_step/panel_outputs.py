"""The memory panel's outputs beside ``memory_panel.json`` (``panel.py``): the CSV, the
figure and the console table, all read from the study's results dict."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

from safety import temporary_path_for

import numpy as np
from analysis.plots import save_figure
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

MODE_LABELS = {"independent": "ind", "comm": "comm", "distance": "dist", "full": "full"}
MODE_COLORS = {
    "independent": "#1b9e77",
    "comm": "#d95f02",
    "distance": "#e7298a",
    "full": "#7570b3",
}
FIGURE_WIDTH = 6.5  # inches: the report's text width
FONT = 8  # points at that width, the smallest text
VARIANTS = ("memoryless", "memory")
CSV_HEADER = [
    "map_seed",
    "condition",
    "mode",
    *(f"{v}_{k}" for v in VARIANTS for k in ("success", "ci_low", "ci_high")),
    "memory_effect",
    "memory_effect_ci_low",
    "memory_effect_ci_high",
    "memory_effect_established",
    "beacon_explorer_success",
]


def fmt(value: float | None) -> str:
    return "" if value is None else f"{value:.4f}"


def write_csv(path: Path, results: dict[str, Any]) -> None:
    """One row per map, condition and mode: success without and with memory (mean over
    seeds, CI), memory's effect (paired by seed) and the beacon explorer's success."""
    with (
        temporary_path_for(path) as temporary,
        open(temporary, "w", newline="", encoding="utf-8") as handle,
    ):
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(CSV_HEADER)
        for entry in results["maps"].values():
            for condition, data in entry["conditions"].items():
                for mode, cell in data["success"].items():
                    row: list[Any] = [entry["map_seed"], condition, mode]
                    for variant in VARIANTS:
                        stats = cell[variant]
                        row += [fmt(stats["mean"]), *map(fmt, stats["ci95"])]
                    effect = data["memory_effect"][mode]
                    row += [fmt(effect["mean"]), *map(fmt, effect["ci95"])]
                    row += [effect["established"], fmt(entry["beacon_explorer_success"])]
                    writer.writerow(row)


def draw_map(ax: Any, entry: dict[str, Any], condition: str) -> None:
    """One map's group: each mode's success without (hollow) and with memory (filled),
    mean over seeds with its CI, and the beacon explorer as a dashed line."""
    cells = entry["conditions"][condition]["success"]
    for x, (mode, cell) in enumerate(cells.items()):
        for offset, variant in ((-0.17, "memoryless"), (0.17, "memory")):
            stats = cell[variant]
            low, high = stats["ci95"]
            color = MODE_COLORS[mode]
            ax.errorbar(
                x + offset,
                stats["mean"],
                yerr=[[stats["mean"] - low], [high - stats["mean"]]],
                fmt="o",
                markersize=4,
                color=color,
                markerfacecolor=color if variant == "memory" else "white",
                elinewidth=1,
                capsize=0,
            )
    if entry["beacon_explorer_success"] is not None:
        ax.axhline(entry["beacon_explorer_success"], color="0.4", linestyle="--", linewidth=0.9)
    ax.set_title(f"map {entry['map_seed']}", fontsize=FONT, pad=2)
    ax.set_xticks(range(len(cells)), [MODE_LABELS[m] for m in cells], fontsize=FONT)
    ax.set_ylim(-0.03, 1.03)
    ax.set_yticks([0, 0.5, 1])
    ax.tick_params(labelsize=FONT, length=2, pad=1)
    ax.set_xlim(-0.5, len(cells) - 0.5)
    ax.grid(axis="y", linewidth=0.4, color="0.85")


def plot_panel(path: Path, results: dict[str, Any], condition: str = "eps") -> None:
    """``memory_panel.png``: one small group per map (:func:`draw_map`), at ``condition``."""
    entries = list(results["maps"].values())
    cols = min(4, len(entries))
    rows = math.ceil(len(entries) / cols)
    fig = Figure(figsize=(FIGURE_WIDTH, 1.55 * rows + 0.75), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols, sharey=True, squeeze=False)).ravel()
    for ax, entry in zip(axes, entries, strict=False):
        draw_map(ax, entry, condition)
    for ax in axes[len(entries) :]:
        ax.set_visible(False)
    for ax in axes[::cols]:
        ax.set_ylabel("success", fontsize=FONT)
    epsilon = results["protocol"]["conditions"][condition]
    handles = [
        Line2D([], [], marker="o", linestyle="", color="0.3", markerfacecolor="white"),
        Line2D([], [], marker="o", linestyle="", color="0.3"),
        Line2D([], [], linestyle="--", color="0.4"),
    ]
    labels = ["memoryless (map panel)", "one-step memory", "beacon explorer"]
    fig.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=FONT, frameon=False)
    fig.suptitle(
        f"Test success at ε = {epsilon} (mean of 5 training seeds, 95 % CI over seeds)",
        fontsize=FONT + 1,
    )
    save_figure(fig, path, dpi=150)


def format_table(results: dict[str, Any], condition: str = "eps") -> str:
    """The console table: per map each mode's success without -> with memory at ε."""
    lines = [f"success at {condition}: memoryless -> one-step memory (* memory effect established)"]
    lines.append("map   " + "".join(f"{m:>20}" for m in MODE_LABELS) + "  beacon")
    for entry in results["maps"].values():
        data = entry["conditions"][condition]
        cells = []
        for mode in MODE_LABELS:
            cell, effect = data["success"][mode], data["memory_effect"][mode]
            mark = "*" if effect["established"] else " "
            cells.append(
                f"{cell['memoryless']['mean']:>9.3f} ->{cell['memory']['mean']:6.3f}{mark}"
            )
        beacon = entry["beacon_explorer_success"]
        lines.append(f"{entry['map_seed']:<6}" + "".join(cells) + f"  {fmt(beacon)}")
    return "\n".join(lines)
