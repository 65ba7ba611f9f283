"""The map panel's outputs beside ``panel.json`` (``studies/panel.py``): the counts of
established effects, ``panel.csv`` (one row per map), ``panel_effects.png`` (each effect
against the map property) and the console table. Everything is read from the study's
results dict, so these files say exactly what ``panel.json`` says."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from safety import temporary_path_for

import numpy as np
from analysis.plots import save_figure
from matplotlib.figure import Figure
from settings import TRAINABLE_MODES

MODE_ORDER = TRAINABLE_MODES
ASSIGNMENT_MAP = 641
VERDICT_MARKS = {"gain": "+", "loss": "-", "unclear": ""}
FIGURE_WIDTH = 6.3  # inches (16 cm): the report places the figure at this width
FONT = 8  # points at that width


def panel_summary(results: dict[str, Any]) -> dict[str, dict]:
    """Per condition and effect: how many maps have it, and which show an established
    gain or loss."""
    summary: dict[str, dict] = {}
    for condition in results["protocol"]["conditions"]:
        summary[condition] = {}
        for name in results["protocol"]["effects"]:
            having = [m for m in results["maps"].values() if name in m["effects"][condition]]
            verdicts = {m["map_seed"]: m["effects"][condition][name]["verdict"] for m in having}
            summary[condition][name] = {
                "maps": len(having),
                "gain_maps": [s for s, v in verdicts.items() if v == "gain"],
                "loss_maps": [s for s, v in verdicts.items() if v == "loss"],
            }
    return summary


def csv_header(results: dict[str, Any]) -> list[str]:
    header = ["map_seed", "target_row", "target_col", results["protocol"]["property"]["name"]]
    header += [f"success_eps_{mode}" for mode in MODE_ORDER]
    for name in results["protocol"]["effects"]:
        header += [f"{name}_eps", f"{name}_eps_ci_low", f"{name}_eps_ci_high", f"{name}_verdict"]
    return header


def write_csv(path: Path, results: dict[str, Any]) -> None:
    """``panel.csv``: per map its target, property, each mode's success at ε (mean over
    seeds) and each effect at ε with its interval and verdict; empty where a mode is missing."""
    prop = results["protocol"]["property"]["name"]
    with (
        temporary_path_for(path) as temporary,
        open(temporary, "w", newline="", encoding="utf-8") as handle,
    ):
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(csv_header(results))
        for entry in results["maps"].values():
            row = [entry["map_seed"], *entry["target"], entry[prop]]
            success = entry["success"]
            row += [f"{success[m]['eps']['mean']:.4f}" if m in success else "" for m in MODE_ORDER]
            for name in results["protocol"]["effects"]:
                effect = entry["effects"]["eps"].get(name)
                if effect is None:
                    row += [""] * 4
                else:
                    low, high = effect["ci95"]
                    row += [f"{v:.4f}" for v in (effect["mean"], low, high)] + [effect["verdict"]]
            writer.writerow(row)


def spread_positions(values: list[int], step: float = 0.09) -> np.ndarray:
    """x positions: each value, maps sharing it spread side by side (in the given order)."""
    positions = np.asarray(values, dtype=float)
    for value in set(values):
        same = [i for i, v in enumerate(values) if v == value]
        positions[same] += (np.arange(len(same)) - (len(same) - 1) / 2) * step
    return positions


def contrast_text(coefficients: dict[str, float]) -> str:
    """``{"full": 1, "comm": -1}`` -> ``"full − comm"``."""
    text = ""
    for mode, coefficient in coefficients.items():
        sign = "−" if coefficient < 0 else "+"
        text += (f" {sign} " if text else ("−" if coefficient < 0 else "")) + mode
    return text


def plot_effects(path: Path, results: dict[str, Any], corrected: dict[str, Any]) -> None:
    """``panel_effects.png``: one panel per effect (ε = 0.05), each map's effect against the
    map property with its 95 % interval; filled markers where the effect is established after
    Holm's correction over the panel's 48 effects (``corrected``: the ``maps`` of
    ``studies.multiplicity.panel_effects``), the assignment's map in red; map seeds beside
    the filled points and the assignment's."""
    prop = results["protocol"]["property"]["name"]
    effects = list(results["protocol"]["effects"])
    maps = list(results["maps"].values())
    fig = Figure(figsize=(FIGURE_WIDTH, 5.0), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True, sharey=True).ravel()
    for ax, name in zip(axes, effects, strict=True):
        having = [m for m in maps if name in m["effects"]["eps"]]
        x = spread_positions([m[prop] for m in having])
        for position, entry in zip(x, having, strict=True):
            effect = entry["effects"]["eps"][name]
            established = corrected[str(entry["map_seed"])][name]["rejected"]
            assignment = entry["map_seed"] == ASSIGNMENT_MAP
            colour = "#c0392b" if assignment else "#2c5d8f"
            mean, (low, high) = 100 * effect["mean"], (100 * v for v in effect["ci95"])  # points
            ax.errorbar(
                position,
                mean,
                [[mean - low], [high - mean]],
                fmt="o" if assignment else "s",
                ms=4.5,
                color=colour,
                elinewidth=0.9,
                capsize=1.5,
                mfc=colour if established else "white",
            )
            if not (established or assignment):
                continue  # unlabelled points near 0 would pile up; panel.csv names them
            ax.annotate(
                str(entry["map_seed"]),
                (position, mean),
                xytext=(-3, -9) if assignment else (3, 2),  # 641 below-left, clear of its row
                textcoords="offset points",
                ha="right" if assignment else "left",
                fontsize=FONT,
                color=colour,
            )
        ax.axhline(0, color="0.4", linewidth=0.8)
        terms = results["protocol"]["effects"][name]["coefficients"]
        ax.set_title(f"{name}\n{contrast_text(terms)}", fontsize=FONT + 1)
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=FONT)
    values = sorted({m[prop] for m in maps})
    axes[0].set_xticks(values)
    axes[0].set_xlim(min(values) - 0.5, max(values) + 0.7)
    for ax in axes[2:]:
        ax.set_xlabel(f"{prop.replace('_', ' ')} (cells)", fontsize=FONT + 1)
    # One label for both rows: two would overlap at this height.
    fig.supylabel("success difference (points, ε = 0.05)", fontsize=FONT + 1)
    handles = [
        axes[0].errorbar([], [], [], fmt="s", color="#2c5d8f", ms=4.5, label=label, mfc=face)
        for label, face in (("established (Holm)", "#2c5d8f"), ("not established", "white"))
    ]
    handles.append(
        axes[0].errorbar(
            [],
            [],
            [],
            fmt="o",
            color="#c0392b",
            ms=4.5,
            label=f"map {ASSIGNMENT_MAP}, the assignment's",
        )
    )
    fig.legend(handles=handles, loc="outside lower center", ncols=3, fontsize=FONT, frameon=False)
    save_figure(fig, path, dpi=150)


def format_table(results: dict[str, Any]) -> str:
    """The console table: per map the property, each mode at ε and each effect at ε
    (``+``/``-``: established gain or loss)."""
    prop = results["protocol"]["property"]["name"]
    effects = list(results["protocol"]["effects"])
    header = f"{'map':>4} {'target':>8} {prop[:8]:>8} " + " ".join(
        f"{m[:11]:>11}" for m in MODE_ORDER
    )
    lines = [header + " " + " ".join(f"{e[:11]:>12}" for e in effects)]
    for entry in results["maps"].values():
        cells = [
            f"{entry['success'][m]['eps']['mean']:11.3f}" if m in entry["success"] else " " * 11
            for m in MODE_ORDER
        ]
        for name in effects:
            effect = entry["effects"]["eps"].get(name)
            text = (
                "" if effect is None else f"{effect['mean']:+.3f}{VERDICT_MARKS[effect['verdict']]}"
            )
            cells.append(f"{text:>12}")
        target = str(tuple(entry["target"]))
        lines.append(f"{entry['map_seed']:>4} {target:>8} {entry[prop]:>8} " + " ".join(cells))
    return "\n".join(lines)
