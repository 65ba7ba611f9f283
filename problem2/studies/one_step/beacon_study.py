"""The screen's winner on maps never seen: do one-step agents learn to home on the beacon?

    python -m studies.one_step.beacon_study      # reads beacon_around.json, trains, tests
    python -m studies.one_step.beacon_study --plot_only   # redraw beacon.png

The cell of the screen's two stages (``beacon_screen.py``, ``beacon_around.py``) whose full
agents scored best on the validation maps trains agents of the four modes (independent,
comm, distance, full) on seeds 0–4 with the one-step map-pool learner and that cell's
options, and each pair is tested from its exported files on the 40 held-out maps exactly as
the one-step and GRU agents are (``held_out_tests.held_out_results``: success, channels
replaced by another episode's at the same step or held constant, CIC, homing). Two
comparisons for the full agents, both paired by seed: against the independent agents trained
the same way (the assignment's ablation: only the mask differs), and against the independent
agents of the screen's best independent cell (``beacon_screen.best_independent``; the
recipe's are the one-step study's own runs, ``one_step_unseen/unseen.json``). One drawn
episode of a full pair shows what happens once one agent stands on the target
(``drawn_episode``).

Outputs: ``results/studies/beacon/`` (``beacon.json``, ``beacon.png``, ``agent_models/``,
``training_logs/``, ``timing.json``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.episodes import recorded_episodes
from analysis.held_out import held_out_maps
from analysis.map_sets import HELD_OUT_MAP_SEEDS
from analysis.runs import load_policy
from analysis.stats import seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_EPSILON, EVAL_SEED
from settings import available_cores
from vector_env import VectorMultiAgentEnv

from studies import map_pool_study
from studies.memory import study as gru_study
from studies.memory.agents import memory_policy
from studies.memory.held_out_tests import CONDITIONS, beacon_homing
from studies.one_step import unseen
from studies.one_step.beacon import BeaconTrainer
from studies.one_step.beacon_around import AROUND_DIR
from studies.one_step.beacon_screen import (
    best_independent,
    check_workers,
    checked_held_out_args,
    config,
)
from studies.staging import run_command, staged_output, study_main, train_into, write_timing

STUDY_DIR = gru_study.RESULTS / "beacon"
MODES = unseen.MODES
SEEDS = unseen.SEEDS  # the reported seeds, paired with the one-step and GRU studies'
BEST_INDEPENDENT = "best_independent"  # the label of the screen's best independent runs


def train_and_test(
    label: str,
    mode: str,
    seed: int,
    changes: dict,
    staging: Path,
    smoke: dict,
    episodes: int,
    progress: Any = None,
) -> dict[str, Any]:
    """Train one (mode, seed) with ``changes`` into ``staging`` and test its exported pair on
    the held-out maps; ``label`` names the run (its mode, or ``best_independent``)."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    cfg = config(mode, seed, changes, smoke)
    env = MultiAgentEnv(grid_size=cfg.grid_shape(), max_steps=cfg.max_steps, seed=cfg.map_seed)
    trainer = BeaconTrainer(env, cfg)
    trainer.name = f"{label}_seed{seed}"
    train_into(trainer, staging, progress, start)
    return unseen.held_out_record(trainer, label, episodes, start, time.perf_counter() - start)


def drawn_episode(models_dir: Path, max_steps: int, episodes: int) -> dict[str, Any]:
    """The first held-out test episode (map order, ε = 0.05, seed 0's full pair) in which one
    agent stands on the target at least 5 steps before the pair meets: per step both agents'
    cells, the distance in cells and the messages sent."""
    agents = tuple(load_policy(models_dir / f"full_seed{SEEDS[0]}_agent_{a}.pt") for a in "AB")
    for map_seed, grid in zip(HELD_OUT_MAP_SEEDS, held_out_maps(), strict=True):
        env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
        policy = memory_policy(agents, env, EVAL_EPSILON, EVAL_SEED + map_seed)
        run = recorded_episodes(env, policy, episodes, seed=EVAL_SEED)
        positions = run.trajectories["positions"]  # (E, T + 1, 2, 2)
        on = (positions == np.array(env.target_position)).all(axis=-1)  # (E, T + 1, 2)
        for e in np.flatnonzero(run.successes):
            length = int(run.lengths[e])
            first = int(np.argmax(on[e, : length + 1].any(axis=1)))
            if length - first >= 5:
                cells = positions[e, : length + 1]
                return {
                    "map_seed": int(map_seed),
                    "episode": int(e),
                    "grid": grid.tolist(),
                    "target": list(env.target_position),
                    "first_on_target_step": first,
                    "met_at_step": length,
                    "positions": cells.tolist(),
                    "distance_cells": np.hypot(*(cells[:, 0] - cells[:, 1]).T).round(3).tolist(),
                    "messages": run.trajectories["messages"][e, :length].round(3).tolist(),
                }
    return {}


def summarise(
    runs: list[dict], winner: str, screen: dict, smoke: dict, episodes: int
) -> dict[str, Any]:
    """The GRU study's summary of the winner's runs, the screen's choice, and full against
    the screen's best independent agents (paired by seed)."""
    mine = [r for r in runs if r["mode"] in MODES]
    cfg = config("full", 0, screen["cells"][winner]["changes"], smoke)
    results = gru_study.summarise(
        cfg, mine, beacon_homing(episodes, cfg.max_steps), gru_study.read_no_memory()
    )
    results["description"] = (
        "one-step memory agents on the map pool trained with the listener's options of the "
        "screen's best cell, tested on held-out maps"
    )
    best = best_independent(screen["cells"])
    full = {r["seed"]: r["success"] for r in mine if r["mode"] == "full"}
    others = {r["seed"]: r["success"] for r in runs if r["mode"] == BEST_INDEPENDENT}
    recipe = unseen.read_json(unseen.STUDY_DIR / "unseen.json")  # the one-step study's runs
    if not others:  # the recipe's independent agents
        others = {s: recipe["runs"][f"independent_seed{s}"]["success"] for s in full}
    results["screen"] = {"winner": winner, "changes": screen["cells"][winner]["changes"]}
    results["best_independent"] = {
        "cell": best,
        "changes": screen["cells"][best]["changes"],
        "success": {c: seed_statistics([others[s][c] for s in full]) for c in CONDITIONS},
        "full_minus_best_independent": {
            c: seed_statistics([full[s][c] - others[s][c] for s in full]) for c in CONDITIONS
        },
    }
    results["departures_from_the_assignment"] = map_pool_study.DEPARTURES | {
        "memory": "the previous observation (masked like the current one) and a one-hot of "
        "the previous move as inputs (27)",
        "training options": "the screen's cell for learning only (studies/one_step/beacon.py)",
    }
    results["one_step_recipe_held_out"] = recipe["held_out"]["modes"]
    return results


def plot(path: Path, results: dict) -> None:
    """Held-out success at ε = 0.05 per mode: one step of memory with the recipe, with the
    screen's options, GRU memory; the explorers as lines."""
    recipe = results["one_step_recipe_held_out"]
    gru = unseen.read_json(gru_study.STUDY_DIR / "memory.json")
    arms = [
        ("one step", "#dd8452", {m: s["eps"] for m, s in recipe.items()}),
        (
            "one step, with the changes",
            "#55a868",
            {m: s["eps"] for m, s in results["held_out"]["modes"].items()},
        ),
        (
            "GRU",
            "#4c72b0",
            {} if gru is None else {m: s["eps"] for m, s in gru["held_out"]["modes"].items()},
        ),
    ]
    unseen.plot_held_out_bars(path, arms)


def run_study(args: argparse.Namespace) -> dict:
    """Train and test the winner's (mode, seed) runs and, unless they are the recipe's or
    the winner's own, the screen's best independent cell; install the outputs whole."""
    screen = unseen.read_json(args.screen)
    if screen is None:
        raise SystemExit(
            f"no screen at {args.screen.resolve()}: run python -m studies.one_step.beacon_screen "
            "then python -m studies.one_step.beacon_around first"
        )
    winner, best = screen["winner"], best_independent(screen["cells"])
    changes = screen["cells"][winner]["changes"]
    seeds = SEEDS[: args.num_seeds]
    with staged_output(args.output_dir) as staging:
        jobs = [
            (m, m, s, changes, staging, args.smoke, args.episodes) for m in MODES for s in seeds
        ]
        best_changes = screen["cells"][best]["changes"]
        if best != "none" and best_changes != changes:
            jobs += [
                (
                    BEST_INDEPENDENT,
                    "independent",
                    s,
                    best_changes,
                    staging,
                    args.smoke,
                    args.episodes,
                )
                for s in seeds
            ]
        steps = args.smoke.get(
            "total_steps", changes.get("total_steps", unseen.map_pool_study.RECIPE["total_steps"])
        )
        runs = run_jobs(train_and_test, jobs, args.workers, ProgressLine(len(jobs), steps))
        results = summarise(runs, winner, screen, args.smoke, args.episodes)
        max_steps = config("full", 0, changes, args.smoke).max_steps
        results["drawn_episode"] = drawn_episode(staging / "agent_models", max_steps, args.episodes)
        write_json_atomic(staging / "beacon.json", results)
        plot(staging / "beacon.png", results)
        write_timing(staging / "timing.json", runs)
    return results


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    add = parser.add_argument
    add("--workers", type=int, default=available_cores(), help="processes (1..64)")
    add("--output_dir", type=Path, default=STUDY_DIR, help="folder written")
    add("--screen", type=Path, default=AROUND_DIR / "beacon_around.json", help="the screen's JSON")
    add("--num_seeds", type=int, default=len(SEEDS), help=f"seeds per mode, 1..{len(SEEDS)}")
    add("--plot_only", action="store_true", help="redraw beacon.png from beacon.json (no runs)")
    add("--total_steps", type=int, default=None, help="smoke runs only: env steps per run")
    add("--episodes_per_map", type=int, default=None, help="smoke runs only: test episodes per map")
    args = parser.parse_args(argv)
    check_workers(parser, args)
    if not 1 <= args.num_seeds <= len(SEEDS):
        parser.error(f"--num_seeds must be in 1..{len(SEEDS)}, got {args.num_seeds}")
    return checked_held_out_args(parser, args, STUDY_DIR)


def format_study(results: dict) -> str:
    """The held-out table, then full minus the best independent cell at epsilon."""
    best = results["best_independent"]
    b = best["full_minus_best_independent"]["eps"]
    low, high = b["ci95"]
    return (
        f"{gru_study.format_table(results)}\n"
        f"full - best independent ({best['cell']}): eps {b['mean']:+.3f} [{low:+.3f}, {high:+.3f}]"
    )


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    return study_main(argv, parse_args, run_study, format_study, plot=("beacon", plot))


if __name__ == "__main__":
    run_command(main)
