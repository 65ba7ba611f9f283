"""What the report's analyses print when ``make`` runs them: a few lines, paths relative to
the repository (``make`` runs them from ``problem2/``), plain characters any console shows.
The tables go to their files (``comparison_table.md``, the JSON and CSV files), not here."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from safety import shown

from output_folder import REPOSITORY


def repository_path(path: str | Path) -> str:
    """``path`` relative to the repository when inside it (``problem2/results/...``), else
    as :func:`safety.shown` gives it."""
    resolved = Path(path).resolve()
    if resolved.is_relative_to(REPOSITORY):
        return resolved.relative_to(REPOSITORY).as_posix()
    return shown(path)


def success_summary(performance: dict[str, Any]) -> list[str]:
    """One line per experiment: each mode's mean success at the evaluation's epsilon."""
    epsilon = performance["protocol"]["conditions"]["eps"]
    lines = []
    for name, experiment in performance["experiments"].items():
        rates = ", ".join(
            f"{mode} {entry['eps']['success_rate']['mean']:.3f}"
            for mode, entry in experiment["modes"].items()
        )
        lines.append(f"{name}: success (eps {epsilon}, mean over seeds) {rates}")
    return lines


def generalization_summary(generalization: dict[str, Any] | None) -> list[str]:
    """One line: each mode's mean success over the unseen maps, at epsilon."""
    if not generalization:
        return []
    means = generalization["mean_over_maps"]
    rates = ", ".join(f"{mode} {stats['eps']['mean']:.3f}" for mode, stats in means.items())
    return [f"unseen maps 0-{len(generalization['maps']) - 1}: success (eps) {rates}"]
