"""Writing what ``python evaluate.py`` measured: the JSON files (every number), the CSV tables
and the figures, all into one output folder (``results/evaluation_results/`` by default).

Files: ``performance.json``, ``communication_analysis.json``, ``failure_analysis.json``,
``generalization.json``, ``interventions.json`` / ``.csv`` / ``.png``,
``communication_measures.json`` / ``.csv`` / ``.png``, ``failure_decomposition.csv`` /
``.png`` (its numbers are in ``performance.json`` and ``failure_analysis.json``),
``mode_differences.csv`` (``performance.json``'s ``mode_differences``), ``held_out.csv``
(``generalization.json``'s ``held_out``), ``comparison_table.md``, ``trajectories.png``
(each mode's episodes shown and its messages per cell; the episodes' cells in
``trajectories.json``), ``comm_heatmap.png``, ``episode_<mode>.gif``.
JSON is written as UTF-8 without NaN or Infinity (a non-finite number is an error).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from safety import temporary_path_for

import numpy as np

from analysis.animation import save_episode_gif
from analysis.estimate_plots import plot_failure_decomposition, plot_interventions, plot_measures
from analysis.plots import (
    EpisodeTrace,
    plot_message_heatmap,
    plot_trajectories,
    strategy_rows,
)
from analysis.report import format_report

CONDITIONS = ("greedy", "eps")


def portable(data: Any) -> Any:
    """``data`` with every float rounded to 12 significant digits. The information measures
    go through NumPy's vectorised logarithms, whose last bit may differ between CPUs; the
    file must have the same bytes on every machine."""
    if isinstance(data, float):
        return float(f"{data:.12g}")
    if isinstance(data, dict):
        return {key: portable(value) for key, value in data.items()}
    if isinstance(data, list | tuple):
        return [portable(value) for value in data]
    return data


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented UTF-8 JSON (final newline) to ``path`` atomically;
    ValueError for NaN or Infinity (they are not JSON)."""
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    with temporary_path_for(path) as temporary:
        temporary.write_text(text, encoding="utf-8")
    return Path(path)


def write_csv(path: str | Path, header: list[str], rows: list[list]) -> Path:
    """Write a CSV table (UTF-8, ``\\n`` line ends, floats to 6 decimals; the JSON files
    hold them unrounded) atomically."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[round(v, 6) if isinstance(v, float) else v for v in row] for row in rows])
    with temporary_path_for(path) as temporary:
        temporary.write_text(buffer.getvalue(), encoding="utf-8")
    return Path(path)


def _ci(stat: dict) -> list:
    low, high = stat["ci95"] if stat.get("ci95") else (None, None)
    return [stat.get("mean"), low, high, stat.get("n")]


def failure_analysis(performance: dict) -> dict[str, Any]:
    """The failure kinds and the failure decomposition of every experiment and mode."""
    protocol = performance["protocol"]
    return {
        "definitions": protocol["failure_definitions"],
        "decomposition_definitions": protocol["failure_decomposition"],
        "experiments": {
            name: {
                mode: {c: entry[c]["failures"] for c in CONDITIONS}
                | {"decomposition": {c: entry[c]["failure_decomposition"] for c in CONDITIONS}}
                | {"baselines": {b: v["failures"] for b, v in experiment["baselines"].items()}}
                for mode, entry in experiment["modes"].items()
            }
            for name, experiment in performance["experiments"].items()
        },
    }


def split_communication(communication: dict) -> tuple[dict, dict, dict]:
    """(communication analysis without the two parts below, interventions, measures)."""
    protocol = communication["protocol"]
    analysis = {"protocol": protocol, "experiments": {}}
    interventions = {
        "protocol": {
            k: protocol[k]
            for k in ("evaluation_seed", "episodes_per_seed", "conditions", "confidence")
        }
        | {k: protocol[k] for k in ("interventions", "channel_interventions", "verdicts")},
        "experiments": {},
    }
    measures = {
        "protocol": {k: protocol[k] for k in ("evaluation_seed", "episodes_per_seed")}
        | {"measures": protocol["measures"], "condition": "greedy"},
        "experiments": {},
    }
    for name, experiment in communication["experiments"].items():
        analysis["experiments"][name] = {**experiment, "modes": {}}
        interventions["experiments"][name], measures["experiments"][name] = {}, {}
        for mode, entry in experiment["modes"].items():
            rest = {k: v for k, v in entry.items() if k not in ("interventions", "measures")}
            rest["per_seed"] = {
                seed: {k: v for k, v in values.items() if k != "measures"}
                for seed, values in entry["per_seed"].items()
            }
            analysis["experiments"][name]["modes"][mode] = rest
            if "interventions" in entry:
                interventions["experiments"][name][mode] = entry["interventions"]
            measures["experiments"][name][mode] = {
                "aggregate": entry["measures"],
                "per_seed": {s: v["measures"] for s, v in entry["per_seed"].items()},
            }
    return analysis, interventions, measures


def intervention_rows(interventions: dict) -> list[list]:
    rows = []
    for name, modes in interventions["experiments"].items():
        for mode, channels in modes.items():
            for channel, entry in channels.items():
                for condition in CONDITIONS:
                    test = entry[condition]
                    for kind, success in test["success"].items():
                        delta = test["delta_success"].get(kind)
                        delta_cells = _ci(delta)[:3] if delta else [0.0, 0.0, 0.0]
                        rows.append(
                            [name, mode, channel, condition, kind, *_ci(success), *delta_cells]
                            + [test["verdict"]]
                        )
    return rows


INTERVENTION_HEADER = [
    "experiment",
    "mode",
    "channel",
    "condition",
    "intervention",
    "success_mean",
    "success_ci95_low",
    "success_ci95_high",
    "seeds",
    "delta_success_mean",
    "delta_success_ci95_low",
    "delta_success_ci95_high",
    "verdict",
]


def measure_rows(measures: dict) -> list[list]:
    rows = []
    for name, modes in measures["experiments"].items():
        for mode, entry in modes.items():
            for bins, values in entry["aggregate"].items():
                for measure, senders in values.items():
                    for sender, stat in senders.items():
                        rows.append([name, mode, bins, measure, sender, *_ci(stat)])
    return rows


MEASURE_HEADER = [
    "experiment",
    "mode",
    "bins",
    "measure",
    "sender",
    "mean",
    "ci95_low",
    "ci95_high",
    "seeds",
]


def decomposition_rows(performance: dict) -> list[list]:
    rows = []
    for name, experiment in performance["experiments"].items():
        for mode, entry in experiment["modes"].items():
            for condition in CONDITIONS:
                failed = entry[condition]["success_rate"]["mean"]
                for key, stat in entry[condition]["failure_decomposition"].items():
                    rows.append([name, mode, condition, 1 - failed, key, *_ci(stat)])
    return rows


DECOMPOSITION_HEADER = [
    "experiment",
    "mode",
    "condition",
    "failed_share",
    "quantity",
    "mean",
    "ci95_low",
    "ci95_high",
    "seeds",
]


def difference_rows(performance: dict) -> list[list]:
    rows = []
    for name, experiment in performance["experiments"].items():
        for conditions in experiment.get("mode_differences", {}).values():
            for condition, d in conditions.items():
                rows.append(
                    [
                        name,
                        d["first"],
                        d["second"],
                        condition,
                        d["mean"],
                        *d["ci95"],
                        *d["ci95_seeds_only"],
                        d["established"],
                        *d["seeds"],
                        d["episodes"],
                    ]
                )
    return rows


DIFFERENCE_HEADER = [
    "experiment",
    "first",
    "second",
    "condition",
    "difference_mean",
    "ci95_low",
    "ci95_high",
    "seeds_only_ci95_low",
    "seeds_only_ci95_high",
    "established",
    "seeds_first",
    "seeds_second",
    "episodes",
]


def held_out_rows(generalization: dict) -> list[list]:
    held_out = generalization["held_out"]
    rows = [
        ["baseline", name, "greedy", "maps", *_ci(stat)]
        for name, stat in held_out["success_rate"].items()
    ]
    for mode, conditions in held_out["modes"].items():
        for condition, entry in conditions.items():
            for quantity, stat in entry.items():
                rows.append(
                    [
                        mode,
                        quantity,
                        condition,
                        "seeds" if "seeds" in quantity else "maps",
                        *_ci(stat),
                    ]
                )
    return rows


HELD_OUT_HEADER = [
    "policy",
    "quantity",
    "condition",
    "ci_over",
    "mean",
    "ci95_low",
    "ci95_high",
    "n",
]


def trace_record(trace: EpisodeTrace) -> dict[str, Any]:
    """An episode shown in ``trajectories.png``: its outcome, each agent's cells as [row, col]
    from the start to the last step, and the message each sent at every step (3 decimals)."""
    return {
        "success": trace.success,
        "length": trace.length,
        "description": trace.description,
        "cells": {name: trace.positions[:, k].astype(int).tolist() for k, name in enumerate("AB")},
        "messages": {
            name: [round(float(m), 3) for m in trace.messages[:, k]] for k, name in enumerate("AB")
        },
    }


def write_outputs(results: dict[str, Any], outcomes: dict, output_dir: Path) -> list[Path]:
    """Write every file of the module docstring to ``output_dir``; the figures show the
    main experiment (or the first one evaluated). Returns the paths written."""
    output_dir = Path(output_dir)
    performance = results["performance"]
    analysis, interventions, measures = split_communication(results["communication"])
    measures = portable(measures)
    written = [
        write_json(output_dir / "performance.json", performance),
        write_json(output_dir / "communication_analysis.json", analysis),
        write_json(output_dir / "failure_analysis.json", failure_analysis(performance)),
        write_json(output_dir / "interventions.json", interventions),
        write_json(output_dir / "communication_measures.json", measures),
        write_csv(
            output_dir / "interventions.csv", INTERVENTION_HEADER, intervention_rows(interventions)
        ),
        write_csv(
            output_dir / "communication_measures.csv", MEASURE_HEADER, measure_rows(measures)
        ),
        write_csv(
            output_dir / "failure_decomposition.csv",
            DECOMPOSITION_HEADER,
            decomposition_rows(performance),
        ),
    ]
    written.append(
        write_csv(
            output_dir / "mode_differences.csv", DIFFERENCE_HEADER, difference_rows(performance)
        )
    )
    if "generalization" in results:
        written.append(write_json(output_dir / "generalization.json", results["generalization"]))
        if "held_out" in results["generalization"]:
            written.append(
                write_csv(
                    output_dir / "held_out.csv",
                    HELD_OUT_HEADER,
                    held_out_rows(results["generalization"]),
                )
            )
    with temporary_path_for(output_dir / "comparison_table.md") as temporary:
        temporary.write_text(format_report(results), encoding="utf-8")
    written.append(output_dir / "comparison_table.md")
    name, outcome = next(iter(outcomes.items()))
    entry = performance["experiments"][name]
    grid = np.array(entry["grid"])
    rows, messages = strategy_rows(outcome.runs, entry)
    heat = [(label, means) for (label, _), means in zip(rows, messages, strict=True)]
    routes = {}
    for mode, (_, traces) in zip(outcome.runs, rows, strict=True):
        routes[mode] = {
            "seed": entry["modes"][mode]["best_seed"],
            "episodes": [trace_record(t) for t in traces if t is not None],
        }
        shown = traces[0] or traces[1]
        if shown is not None:
            title = f"{mode}: {'success' if shown.success else 'failure'}"
            written.append(save_episode_gif(shown, grid, output_dir / f"episode_{mode}.gif", title))
    written.append(plot_trajectories(rows, grid, output_dir / "trajectories.png", messages))
    episodes_shown = {"target": entry["target"], "modes": routes}
    written.append(write_json(output_dir / "trajectories.json", episodes_shown))
    written.append(plot_message_heatmap(heat, grid, output_dir / "comm_heatmap.png"))
    main_measures = {m: v["aggregate"] for m, v in measures["experiments"][name].items()}
    written.append(plot_measures(main_measures, "K2", output_dir / "communication_measures.png"))
    written.append(
        plot_failure_decomposition(entry["modes"], output_dir / "failure_decomposition.png")
    )
    if interventions["experiments"].get(name):
        written.append(
            plot_interventions(interventions["experiments"][name], output_dir / "interventions.png")
        )
    return written
