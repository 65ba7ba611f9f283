"""Figures of estimates with their intervals over seeds, from ``python evaluate.py``'s
results: the channel interventions, the communication measures and the failure
decomposition. Drawn like :mod:`analysis.plots`' figures, at the width the report places
them (``WIDTHS``) with text of at least ``MIN_FONT`` points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from vector_env import MASKED_INPUTS, MESSAGE_INDEX

from analysis.plots import AGENT_COLOURS, MIN_FONT, WIDTHS, legible, save_figure


def draw_estimates(ax: Axes, rows: np.ndarray, stats: list[dict], scale: float, **style) -> None:
    """Means with their 95 % CI as dots and whiskers at heights ``rows`` (``stats``: seed
    statistics with ``mean`` and ``ci95``, times ``scale``); None draws nothing."""
    shown = [(row, s) for row, s in zip(rows, stats, strict=True) if s is not None]
    if not shown:
        return
    means = scale * np.array([s["mean"] for _, s in shown])
    bounds = scale * np.array([s["ci95"] for _, s in shown])
    errors = np.maximum(np.stack([means - bounds[:, 0], bounds[:, 1] - means]), 0)
    ax.errorbar(
        means,
        [row for row, _ in shown],
        xerr=errors,
        capsize=2.5,
        linestyle="none",
        markersize=5,
        elinewidth=1.2,
        **style,
    )


CONDITION_STYLES = {  # evaluation condition -> legend label, marker and colour
    "greedy": {"label": "greedy", "fmt": "o", "color": "#4c72b0"},
    "eps": {"label": "ε = 0.05", "fmt": "s", "color": "#dd8452"},
}


def plot_interventions(modes: dict[str, dict], path: str | Path) -> Path:
    """Δsuccess (intervention − real) with its 95 % CI over seeds, one panel per mode and
    channel (``modes``: mode -> channel -> the ``interventions`` entry), greedy and
    ε-greedy side by side, on one linear axis (a 1-point change is drawn as small as it
    is beside a 30-point one)."""
    panels = [
        (mode, channel, entry)
        for mode, channels in modes.items()
        for channel, entry in channels.items()
    ]
    with legible():
        fig = Figure(
            figsize=(WIDTHS["interventions"], 1.35 * len(panels) + 1.0), layout="constrained"
        )
        axes = np.atleast_1d(fig.subplots(len(panels), 1, squeeze=False, sharex=True)[:, 0])
        for ax, (mode, channel, entry) in zip(axes, panels, strict=True):
            kinds = list(entry["greedy"]["delta_success"])
            rows = np.arange(len(kinds))
            for offset, (condition, style) in zip(
                (-0.17, 0.17), CONDITION_STYLES.items(), strict=True
            ):
                stats = [entry[condition]["delta_success"][k] for k in kinds]
                draw_estimates(ax, rows + offset, stats, 100, **style)  # percentage points
            ax.axvline(0, color="black", linewidth=0.8)
            ax.set_yticks(rows, [k.replace("_", " ") for k in kinds])
            ax.set_ylim(len(kinds) - 0.5, -0.5)
            ax.grid(True, axis="x", alpha=0.3)
            verdict = entry["eps"]["verdict"]
            ax.set_title(f"{mode}: {channel} (verdict at ε = 0.05: {verdict})")
        bounds = [
            100 * entry[c]["delta_success"][k]["ci95"][side]
            for _, _, entry in panels
            for c in CONDITION_STYLES
            for k in entry[c]["delta_success"]
            for side in (0, 1)
        ]
        span = max(*bounds, 0) - min(*bounds, 0)
        axes[-1].set_xlim(min(*bounds, 0) - 0.05 * span, max(*bounds, 0) + 0.05 * span)
        axes[-1].set_xlabel("Δ success vs the real input (points, 95 % CI over seeds)")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=2)
        fig.suptitle("What happens when an input channel is replaced")
        return save_figure(fig, path, dpi=200)


MEASURE_TITLES = {"cic": "causal influence of communication (CIC)"}


def plot_measures(modes: dict[str, dict], bins: str, path: str | Path) -> Path:
    """Each communication measure (``modes``: mode -> {"K2": {measure: {sender: seed
    statistics}}}) per mode, senders A and B: mean (dot and value) with its 95 % CI over
    seeds, every panel on one scale of bits. Where the receiver does not see the message
    (``vector_env.MASKED_INPUTS``), its CIC is zero by construction and said so, not drawn."""
    measures = list(next(iter(modes.values()))[bins])
    highs = [s["ci95"][1] for m in modes.values() for e in m[bins].values() for s in e.values()]
    limit = 1.3 * max(*highs, 0.01)  # room for the values written beside the whiskers
    with legible():
        fig = Figure(figsize=(WIDTHS["measures"], 1.0 * len(measures) + 1.3), layout="constrained")
        axes = fig.subplots(len(measures), 1, squeeze=False, sharex=True)[:, 0]
        rows = np.arange(len(modes))
        for ax, measure in zip(axes, measures, strict=True):
            for offset, sender in zip((-0.18, 0.18), "AB", strict=True):
                colour = AGENT_COLOURS["AB".index(sender)]
                stats = [
                    None
                    if measure == "cic" and MESSAGE_INDEX in MASKED_INPUTS.get(mode, ())
                    else modes[mode][bins][measure][sender]
                    for mode in modes
                ]
                draw_estimates(
                    ax, rows + offset, stats, 1, fmt="o", color=colour, label=f"sender {sender}"
                )
                for row, stat in zip(rows + offset, stats, strict=True):
                    if stat is not None:
                        ax.text(
                            stat["ci95"][1] + 0.01 * limit,
                            row,
                            f" {stat['mean']:.3f}",
                            va="center",
                            fontsize=MIN_FONT - 1,
                            color=colour,
                        )
            for row, mode in zip(rows, modes, strict=True):
                if measure == "cic" and MESSAGE_INDEX in MASKED_INPUTS.get(mode, ()):
                    ax.text(
                        0.01 * limit,
                        row,
                        "0 by construction: the partner does not see it",
                        va="center",
                        fontsize=MIN_FONT - 1,
                    )
            ax.set_yticks(rows, list(modes))
            ax.set_ylim(len(modes) - 0.5, -0.5)
            ax.set_xlim(0, limit)
            ax.grid(True, axis="x", alpha=0.3)
            ax.set_title(MEASURE_TITLES.get(measure, measure.replace("_", " ")))
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
        navigation, timing = 100 * np.array(navigation), 100 * np.array(timing)  # percent
        ax.barh(rows, navigation, color="#8172b3", label="navigation: an agent never reached it")
        ax.barh(
            rows,
            timing,
            left=navigation,
            color="#ccb974",
            label="timing: both reached it, never together",
        )
        ax.set_yticks(rows, labels)
        ax.invert_yaxis()
        ax.set_xlabel("test episodes that fail (%, mean over seeds)")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=1)
        fig.suptitle("Why episodes fail")
        return save_figure(fig, path, dpi=200)
