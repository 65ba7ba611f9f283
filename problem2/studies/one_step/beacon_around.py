"""The screen's second stage: κ, the share of reverse starts and the training length around
the first stage's winner, on the same training seeds and validation maps.

    python -m studies.one_step.beacon_around   # reads beacon_screen.json, trains, writes

Around the winner W of the first stage (``beacon_screen.py``; its options in ``changes``):
W with κ = 1 and κ = 4 if it has homing shaping, W with reverse starts at shares 0.25 (and
0.75 if W has them already), and W trained for 2 million steps instead of 1 (``around``).
Each cell trains full and independent agents on seeds 100–102 with the cell's options; the
distance's change acts on nothing an independent agent sees (a test holds the weights equal),
so its independent agents are the twins of its full agents. The table holds the first
stage's cells and these, and the winner over all of them is the cell whose full agents score
best on the validation maps at ε = 0.05; ``beacon_study`` tests it on the held-out maps.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

from studies.memory import study as gru_study
from studies.one_step import unseen
from studies.one_step.beacon_screen import (
    MILLION,
    SCREEN_DIR,
    TRAINING_SEEDS,
    best_independent,
    cell_table,
    checked_stage_args,
    stage_parser,
    train_cells,
    winner,
)
from studies.staging import run_command, staged_output, study_main

AROUND_DIR = gru_study.RESULTS / "beacon_around"
HOMING = (1.0, 4.0)  # the first stage's κ is 2
LONGER = 2 * MILLION


def around(name: str, changes: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The second stage's cells around the first stage's winner ``name`` (options ``changes``):
    each cell's options and the modes it trains."""
    variants: dict[str, dict[str, Any]] = {}
    if "homing_potential" in changes:
        for kappa in HOMING:
            variants[f"{name} k={kappa:g}"] = {"homing_potential": kappa}
    shares = (0.25, 0.75) if "reverse_starts" in changes else (0.25,)
    for share in shares:
        variants[f"{name} R={share:g}"] = {"reverse_starts": share}
    variants[f"{name} 2M"] = {"total_steps": LONGER}
    modes = ["full", "independent"]
    return {cell: {"changes": changes | v, "modes": modes} for cell, v in variants.items()}


def summarise(runs: list[dict], first: dict[str, Any], cells: dict[str, Any]) -> dict[str, Any]:
    """Both stages' cells in one table (the first stage's as it wrote them), the winner over
    all of them and the best independent cell."""
    table = first["cells"] | cell_table(runs, cells, {c: c for c in cells}, TRAINING_SEEDS)
    return {
        "description": "the listener's training options for one-step memory agents on the map "
        "pool, both stages of the screen, on training seeds, judged on the validation maps "
        "(best checkpoint)",
        "training_seeds": list(TRAINING_SEEDS),
        "first_stage_winner": first["winner"],
        "second_stage": list(cells),
        "cells": table,
        "winner": winner(table),
        "best_independent": best_independent(table),
    }


def run_stage(args: argparse.Namespace) -> dict:
    """Train the second stage's runs; write ``beacon_around.json`` and the training logs."""
    first = unseen.read_json(args.screen)
    if first is None:
        raise SystemExit(
            f"no first stage at {args.screen.resolve()}: run "
            "python -m studies.one_step.beacon_screen first"
        )
    cells = around(first["winner"], first["cells"][first["winner"]]["changes"])
    with staged_output(args.output_dir, subfolders=()) as staging:
        results = summarise(train_cells(cells, args, staging), first, cells)
        write_json_atomic(staging / "beacon_around.json", results)
    return results


def format_stage(results: dict) -> str:
    """One line per second-stage cell: full and independent validation success, difference."""
    lines = [f"{'cell':<14} {'full':>6} {'indep':>6} {'diff':>7}"]
    for cell in results["second_stage"]:
        entry = results["cells"][cell]
        full, indep = entry["full"]["eps"]["mean"], entry["independent"]["eps"]["mean"]
        diff = entry["full_minus_independent_eps"]["mean"]
        lines.append(f"{cell:<14} {full:6.3f} {indep:6.3f} {diff:+7.3f}")
    lines.append(f"winner: {results['winner']}; best independent: {results['best_independent']}")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = stage_parser(__doc__.split("\n\n")[0], AROUND_DIR)
    parser.add_argument(
        "--screen", type=Path, default=SCREEN_DIR / "beacon_screen.json", help="the first stage"
    )
    return checked_stage_args(parser, parser.parse_args(argv), AROUND_DIR)


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    return study_main(argv, parse_args, run_stage, format_stage)


if __name__ == "__main__":
    run_command(main)
