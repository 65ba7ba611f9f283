"""The listener at two million steps: one pre-named cell of the screen, confirmed on training
seeds and validation maps before any held-out test.

    python -m studies.one_step.beacon_long      # 16 runs, writes beacon_long.json

The cell is the screen's R + H + D (``beacon_screen.cell_changes("RHD")``: reverse starts at
share 0.5, homing shaping κ = 2, the distance's change) for full agents and its independent
twin R + H (the distance's change acts on nothing an independent agent sees), both trained
2 million steps instead of the screen's 1, on training seeds 100–107. Every run is judged as
the screen judges (``beacon_screen.train_cell``): its best checkpoint on the validation maps
at ε = 0.05; full − independent is paired by seed with a bootstrap CI. The pass rule (``RULE``,
stated before the runs) decides whether the held-out study of the cell runs. Outputs in
``--output_dir``: ``beacon_long.json``, ``training_logs/`` per cell and ``timing.json``
(wall times, not a result).
"""

from __future__ import annotations

import argparse
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

from studies.memory import study as gru_study
from studies.one_step.beacon_screen import (
    MILLION,
    OPTIONS,
    cell_changes,
    cell_table,
    checked_stage_args,
    stage_parser,
    train_cells,
)
from studies.staging import run_command, staged_output, study_main

LONG_DIR = gru_study.RESULTS / "beacon_long"
SEEDS = tuple(range(100, 108))  # training seeds: never reported as results
LONGER = 2 * MILLION
FULL, INDEPENDENT = "RHD 2M", "RH 2M"
MARGIN = 0.08  # success rate: 8 points
RULE = (
    "passes if full - independent (paired by training seed; validation maps, best checkpoint, "
    "eps = 0.05) has mean >= +8 points and its 95 % bootstrap interval's lower end above 0"
)


def long_cells() -> dict[str, dict[str, Any]]:
    """The two cells: R + H + D for full agents and R + H for independent ones, at 2 M."""
    longer = {"total_steps": LONGER}
    return {
        FULL: {"changes": cell_changes("RHD") | longer, "modes": ["full"]},
        INDEPENDENT: {"changes": cell_changes("RH") | longer, "modes": ["independent"]},
    }


def verdict(difference: dict[str, Any]) -> dict[str, Any]:
    """The pass rule applied to full − independent's :func:`seed_statistics`."""
    mean, low = difference["mean"], difference["ci95"][0]
    passed = round(mean, 9) >= MARGIN and low > 0  # rounded: 0.08 summed from rates is 0.08
    return {"rule": RULE, "mean": mean, "ci95_low": low, "passed": passed}


def summarise(
    runs: list[dict], cells: dict[str, dict[str, Any]], total_steps: int
) -> dict[str, Any]:
    """The screen's table of the two cells over ``SEEDS`` (per-seed values kept), full paired
    with its independent twin, and the pass rule's verdict."""
    table = cell_table(runs, cells, {FULL: INDEPENDENT, INDEPENDENT: None}, SEEDS)
    return {
        "description": "the listener's R + H + D cell (full) and its independent twin R + H, "
        "trained 2 million steps on training seeds, judged on the validation maps (best "
        "checkpoint, eps = 0.05) as the screen judges",
        "training_seeds": list(SEEDS),
        "total_steps": total_steps,
        "options": OPTIONS,
        "cells": table,
        "pass_rule": verdict(table[FULL]["full_minus_independent_eps"]),
    }


def run_long(args: argparse.Namespace) -> dict:
    """Train the two cells' runs; write ``beacon_long.json`` and the training logs."""
    cells = long_cells()
    with staged_output(args.output_dir, subfolders=()) as staging:
        runs = train_cells(cells, args, staging, SEEDS)
        results = summarise(runs, cells, args.smoke.get("total_steps", LONGER))
        write_json_atomic(staging / "beacon_long.json", results)
    return results


def format_long(results: dict) -> str:
    """Per seed full, independent and their difference (points); means with CIs; verdict."""
    cells = results["cells"]
    columns = {
        "full": (cells[FULL]["full"]["eps"], 1, ".3f"),
        "indep": (cells[INDEPENDENT]["independent"]["eps"], 1, ".3f"),
        "diff": (cells[FULL]["full_minus_independent_eps"], 100, "+.1f"),  # points
    }
    lines = ["seed   " + " ".join(f"{name:>6}" for name in columns)]
    for k, seed in enumerate(results["training_seeds"]):
        shown = (
            format(scale * s["per_seed"][k], fmt).rjust(6) for s, scale, fmt in columns.values()
        )
        lines.append(f"{seed:<6} " + " ".join(shown))
    for name, (stats, scale, fmt) in columns.items():
        mean, low, high = (scale * v for v in (stats["mean"], *stats["ci95"]))
        lines.append(f"{name:<6} {mean:{fmt}} [{low:{fmt}}, {high:{fmt}}]")
    rule = results["pass_rule"]
    lines.append(f"pass rule: {'passed' if rule['passed'] else 'not passed'} ({rule['rule']})")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = stage_parser(__doc__.split("\n\n")[0], LONG_DIR)
    return checked_stage_args(parser, parser.parse_args(argv), LONG_DIR)


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    return study_main(argv, parse_args, run_long, format_long)


if __name__ == "__main__":
    run_command(main)
