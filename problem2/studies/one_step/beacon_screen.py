"""The screen of the listener's training options, on training seeds and validation maps only.

    python -m studies.one_step.beacon_screen        # every cell, writes beacon_screen.json

Cells (``SCREEN``): the 2 × 2 × 2 of reverse starts (R, share 0.5), homing shaping (H,
κ = 2) and the distance's change (D) for full agents, and the 2 × 2 of R and H for
independent agents (D hides nothing from agents that do not see the distance: an
independent run of a cell with D is the same cell's run without it); then the
prototype's cell R + H + D with a positive-listening loss (λ = 0.1, full only).
Every run is the one-step map-pool learner (``map_pool_study.RECIPE``) with its cell's
options (:class:`~studies.one_step.beacon.BeaconConfig`) on training seeds 100–102, judged
by its best checkpoint on the validation maps at ε = 0.05 (the held-out maps are never
used for a choice). The winner (:func:`winner`) is the cell whose full agents score best;
the second stage (``beacon_around.py``) varies it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

import torch
from analysis.stats import seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from multi_agent_env import MultiAgentEnv
from settings import SettingError, available_cores, usage, validated

from studies import map_pool_study
from studies.memory import study as gru_study
from studies.one_step import unseen
from studies.one_step.beacon import BeaconConfig, BeaconTrainer
from studies.staging import (
    best_env_steps,
    best_selection,
    run_command,
    staged_output,
    study_main,
    train_into,
)

SCREEN_DIR = gru_study.RESULTS / "beacon_screen"
TRAINING_SEEDS = (100, 101, 102)  # never reported as results
MILLION = 1_000_000
OPTIONS: dict[str, dict[str, Any]] = {
    "R": {"reverse_starts": 0.5},
    "H": {"homing_potential": 2.0},
    "D": {"distance_change": True},
}
FACTORIAL = ("none", "R", "H", "D", "RH", "RD", "HD", "RHD")
# Cells beyond the factorial: (name, base cell, changes, modes).
AROUND: tuple[tuple[str, str, dict[str, Any], tuple[str, ...]], ...] = (
    ("RHD+listening", "RHD", {"listening": 0.1}, ("full",)),
)


def cell_changes(cell: str) -> dict[str, Any]:
    """The BeaconConfig fields of a factorial cell ("none" or letters of ``OPTIONS``)."""
    changes: dict[str, Any] = {}
    for letter in "" if cell == "none" else cell:
        changes |= OPTIONS[letter]
    return changes


def screen_cells() -> dict[str, dict[str, Any]]:
    """Every cell: its changes and the modes it trains."""
    cells = {c: {"changes": cell_changes(c), "modes": ["full"]} for c in FACTORIAL}
    for cell in FACTORIAL:
        if "D" not in cell:
            cells[cell]["modes"].append("independent")
    for name, base, changes, modes in AROUND:
        cells[name] = {"changes": cell_changes(base) | changes, "modes": list(modes)}
    return cells


def independent_twin(cell: str, cells: dict[str, dict[str, Any]]) -> str | None:
    """The cell whose independent runs pair with ``cell``'s full runs: itself, or the same
    cell without D (the distance's change acts on nothing an independent agent sees)."""
    if "independent" in cells[cell]["modes"]:
        return cell
    if cell in FACTORIAL:
        twin = cell.replace("D", "") or "none"
        return twin if "independent" in cells[twin]["modes"] else None
    return None


def config(mode: str, seed: int, changes: dict[str, Any], smoke: dict[str, Any]) -> BeaconConfig:
    """The recipe for one run with the cell's ``changes`` (``smoke``: shortened runs)."""
    fields = map_pool_study.RECIPE | {"seeds": [], "workers": 1} | changes | smoke
    return validated(BeaconConfig(**fields, mode=mode, seed=seed))


def train_cell(
    cell: str, mode: str, seed: int, changes: dict, staging: Path, smoke: dict, progress: Any = None
) -> dict[str, Any]:
    """Train one (cell, mode, seed); its validation results (models are not kept)."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    cfg = config(mode, seed, changes, smoke)
    env = MultiAgentEnv(grid_size=cfg.grid_shape(), max_steps=cfg.max_steps, seed=cfg.map_seed)
    trainer = BeaconTrainer(env, cfg)
    folder = staging / cell.replace(" ", "_").replace("+", "_").replace("=", "")
    log = train_into(trainer, folder, progress, start, f"{cell}/{trainer.name}")
    for path in trainer.models_dir.rglob("*.pt"):
        path.unlink()  # judged on the validation maps only
    return {
        "cell": cell,
        "mode": mode,
        "seed": seed,
        "best": best_selection(trainer),
        "best_env_steps": best_env_steps(trainer),
        "last": {"greedy": log[-1]["eval_success_greedy"], "eps": log[-1]["eval_success_eps"]},
        "seconds": round(time.perf_counter() - start, 1),
    }


def cell_table(
    runs: list[dict], cells: dict[str, dict[str, Any]], twins: dict[str, str | None], seeds: tuple
) -> dict[str, Any]:
    """Per cell and mode the validation success over ``seeds`` (best checkpoint, ε and
    greedy), and full − independent paired by seed against the cell's twin in ``twins``."""
    found = {(r["cell"], r["mode"], r["seed"]): r for r in runs}
    table: dict[str, Any] = {}
    for cell, spec in cells.items():
        entry: dict[str, Any] = {"changes": spec["changes"], "modes": spec["modes"]}
        for mode in spec["modes"]:
            mine = [found[(cell, mode, s)] for s in seeds]
            entry[mode] = {
                c: seed_statistics([r["best"][c] for r in mine]) for c in ("eps", "greedy")
            }
            entry[mode]["best_env_steps"] = [r["best_env_steps"] for r in mine]
        twin = twins[cell]
        entry["independent_from"] = twin
        if twin is not None:
            entry["full_minus_independent_eps"] = seed_statistics(
                [
                    found[(cell, "full", s)]["best"]["eps"]
                    - found[(twin, "independent", s)]["best"]["eps"]
                    for s in seeds
                ]
            )
        table[cell] = entry
    return table


def summarise(runs: list[dict], cells: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The screen's table (:func:`cell_table`, twins by :func:`independent_twin`) and its
    winner."""
    twins = {cell: independent_twin(cell, cells) for cell in cells}
    table = cell_table(runs, cells, twins, TRAINING_SEEDS)
    return {
        "description": "the listener's training options for one-step memory agents on the map "
        "pool, on training seeds, judged on the validation maps (best checkpoint)",
        "training_seeds": list(TRAINING_SEEDS),
        "options": OPTIONS,
        "cells": table,
        "winner": winner(table),
    }


def winner(table: dict[str, Any]) -> str:
    """The cell whose full agents have the highest mean validation success at ε = 0.05
    (declared before the screen ran; on a tie, the first in the screen's order)."""
    return max(table, key=lambda cell: table[cell]["full"]["eps"]["mean"])


def best_independent(table: dict[str, Any]) -> str:
    """The cell whose independent agents score best on the validation maps at ε = 0.05."""
    trained = [c for c in table if "independent" in table[c]["modes"]]
    return max(trained, key=lambda cell: table[cell]["independent"]["eps"]["mean"])


def train_cells(
    cells: dict[str, dict[str, Any]],
    args: argparse.Namespace,
    staging: Path,
    seeds: tuple[int, ...] = TRAINING_SEEDS,
) -> list:
    """Train every (cell, mode, seed in ``seeds``) of ``cells`` into ``staging``, the longest
    runs first; their records (:func:`train_cell`), and their wall times in ``timing.json``."""
    jobs = [
        (cell, mode, seed, spec["changes"], staging, args.smoke)
        for cell, spec in cells.items()
        for mode in spec["modes"]
        for seed in seeds
    ]
    jobs.sort(key=lambda job: -job[3].get("total_steps", MILLION))  # longest first
    steps = [args.smoke.get("total_steps", job[3].get("total_steps", MILLION)) for job in jobs]
    progress = ProgressLine(len(jobs), sum(steps) // len(steps))  # mean steps per run
    runs = run_jobs(train_cell, jobs, args.workers, progress)
    timing = {f"{r['cell']}/{r['mode']}_seed{r['seed']}": r["seconds"] for r in runs}
    write_json_atomic(staging / "timing.json", timing)  # wall times: not a result
    return runs


def run_screen(args: argparse.Namespace) -> dict:
    """Train every cell's runs; write ``beacon_screen.json`` and the training logs."""
    cells = screen_cells()
    with staged_output(args.output_dir, subfolders=()) as staging:
        results = summarise(train_cells(cells, args, staging), cells)
        write_json_atomic(staging / "beacon_screen.json", results)
    return results


def format_screen(results: dict) -> str:
    """One line per cell: full and independent validation success and their difference."""
    lines = [f"{'cell':<18} {'full':>6} {'indep':>6} {'diff':>7}"]
    for cell, entry in results["cells"].items():
        full = entry["full"]["eps"]["mean"]
        twin = entry["independent_from"]
        indep = results["cells"][twin]["independent"]["eps"]["mean"] if twin else None
        shown = f"{indep:6.3f}" if indep is not None else "     -"
        diff = entry.get("full_minus_independent_eps", {}).get("mean")
        lines.append(
            f"{cell:<18} {full:6.3f} {shown} {'' if diff is None else format(diff, '+7.3f')}"
        )
    lines.append(f"winner: {results['winner']}")
    return "\n".join(lines)


def stage_parser(description: str, default_dir: Path) -> argparse.ArgumentParser:
    """The flags of a screen's stage (``default_dir``: where its results go)."""
    parser = argparse.ArgumentParser(description=description, allow_abbrev=False)
    add = parser.add_argument
    add("--workers", type=int, default=available_cores(), help="processes (1..64)")
    add("--output_dir", type=Path, default=default_dir, help="folder written")
    add("--total_steps", type=int, default=None, help="smoke runs only: env steps per run")
    return parser


def checked_stage_args(
    parser: argparse.ArgumentParser, args: argparse.Namespace, default_dir: Path
) -> argparse.Namespace:
    """``args`` checked, with ``args.smoke`` the settings of a smoke run (``--total_steps``,
    refused into ``default_dir``) or empty."""
    check_workers(parser, args)
    args.smoke = {}
    if args.total_steps is not None:
        if args.output_dir.resolve() == default_dir.resolve():
            parser.error("--total_steps is for smoke runs: give another --output_dir")
        if args.total_steps < 1:
            parser.error(f"--total_steps must be an integer >= 1, got {args.total_steps}")
        interval = max(1, args.total_steps // 2)
        args.smoke = {
            "total_steps": args.total_steps,
            "eval_interval": interval,
            "eval_episodes": 20,
        }
    refuse_unlearnable(parser, args.smoke)
    return args


def check_workers(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """A usage error unless ``--workers`` is in 1..64."""
    if not 1 <= args.workers <= 64:
        parser.error(f"--workers must be in 1..64, got {args.workers}")


def checked_held_out_args(
    parser: argparse.ArgumentParser, args: argparse.Namespace, default_dir: Path
) -> argparse.Namespace:
    """A held-out study's ``args`` with ``args.episodes`` (test episodes per map) and
    ``args.smoke`` (the settings of a smoke run: ``--total_steps``, ``--episodes_per_map``,
    refused into ``default_dir``) set; ``--workers`` is checked by the caller."""
    smoke = {
        k: v for k in ("total_steps", "episodes_per_map") if (v := getattr(args, k)) is not None
    }
    for name, value in smoke.items():
        if value < 1:
            parser.error(f"--{name} must be an integer >= 1, got {value}")
    if smoke and args.output_dir.resolve() == default_dir.resolve():
        parser.error(
            "--total_steps and --episodes_per_map are for smoke runs: give another --output_dir"
        )
    args.episodes = smoke.pop("episodes_per_map", unseen.EPISODES_PER_MAP)
    if "total_steps" in smoke:
        smoke |= {"eval_interval": max(1, smoke["total_steps"] // 2), "eval_episodes": 20}
    refuse_unlearnable(parser, smoke)
    args.smoke = smoke
    return args


def refuse_unlearnable(parser: argparse.ArgumentParser, smoke: dict[str, Any]) -> None:
    """A usage error, before any run starts, if the runs' settings are refused (e.g. a smoke
    budget that ends before the first update)."""
    try:
        config("full", TRAINING_SEEDS[0], {}, smoke)
    except SettingError as error:
        parser.error(usage(error))


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = stage_parser(__doc__.split("\n\n")[0], SCREEN_DIR)
    return checked_stage_args(parser, parser.parse_args(argv), SCREEN_DIR)


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    return study_main(argv, parse_args, run_screen, format_screen)


if __name__ == "__main__":
    run_command(main)
