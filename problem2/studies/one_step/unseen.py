"""One-step memory on maps never seen: the map-pool study's agents with one step of memory.

    python -m studies.one_step.unseen              # 4 modes x seeds 0-4, held-out tests
    python -m studies.one_step.unseen --levers     # the levers, on training seeds 100, 101

Agents of the four modes (independent, comm, distance, full) with the one-step memory of
``agents.py`` learn on the map pool with the map-pool study's recipe
(``map_pool_study.RECIPE``, unchanged) and are tested from their exported files (memory
contract) on the 40 held-out maps exactly as the GRU agents of ``studies/memory`` are
(``held_out_tests.held_out_results``: success, channel interventions, CIC, homing), so the
table sets them beside the memoryless agents of the map-pool study (same seeds), the GRU
agents and the hand-written explorers.

``--levers`` tries settings that might make the partner's signal worth something to a
learner (``LEVERS``), on training seeds never reported, judged on the validation maps only:
full against independent, best checkpoint, greedy and at ε = 0.05.

Outputs: ``results/studies/one_step_unseen/`` (``unseen.json``, ``unseen.png``,
``agent_models/``, ``training_logs/``, ``timing.json``) and, with ``--levers``,
``results/studies/one_step_unseen_levers/levers.json`` with the runs' training logs.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

import torch
from analysis.runs import load_policy
from analysis.stats import seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from matplotlib.figure import Figure
from multi_agent_env import MultiAgentEnv
from settings import TRAINABLE_MODES, available_cores, validated

from studies import map_pool_study
from studies.memory import study as gru_study
from studies.memory.held_out_tests import CONDITIONS, beacon_homing, held_out_results
from studies.one_step.agents import OneStepMemoryEnv, OneStepMemoryTrainer
from studies.pool_training import CurriculumEnv, PoolConfig, PoolTrainer
from studies.staging import (
    best_env_steps,
    best_selection,
    run_command,
    staged_output,
    study_main,
    train_into,
    write_timing,
)

RESULTS = gru_study.RESULTS
STUDY_DIR = RESULTS / "one_step_unseen"
LEVERS_DIR = RESULTS / "one_step_unseen_levers"
MODES = TRAINABLE_MODES
SEEDS = (0, 1, 2, 3, 4)  # the map-pool and memory studies' seeds: runs pair by seed
EPISODES_PER_MAP = 500  # as the GRU agents'
TRAINING_SEEDS = (100, 101)  # the levers' (never reported)
LEVER_MODES = ("independent", "full")
LEVERS: dict[str, dict[str, Any]] = {
    "recipe": {},
    "twice_as_long": {"total_steps": 2 * map_pool_study.RECIPE["total_steps"]},
    "dial_noise_2": {"comm_noise": 2.0},
}
LEVER_WORDS = {
    "recipe": "the map-pool recipe with one-step memory",
    "twice_as_long": "twice the environment steps: learning to read a signal may take longer "
    "than learning to move",
    "dial_noise_2": "DIAL noise sigma = 2 on the message logit (1 in the recipe): noise pushes "
    "the sender towards saturated, easier-to-read messages (Foerster et al. 2016)",
}
# A lever changes nothing for agents that hear no message: they are the recipe's runs.
UNCHANGED_FOR_INDEPENDENT = ("dial_noise_2",)


class PooledOneStepEnv(OneStepMemoryEnv, CurriculumEnv):
    """The map pool's copies with one-step memory inputs (27 for the 3 x 3 window); reverse
    starts where a trainer sets their share (none here: ``beacon.BeaconTrainer`` does)."""


class PooledOneStepTrainer(OneStepMemoryTrainer, PoolTrainer):
    """The map-pool learner (pool, bonuses, shared weights) on one-step memory inputs,
    exported under the memory contract."""

    vector_env_class = PooledOneStepEnv


def recipe(**changes: Any) -> PoolConfig:
    """The map-pool study's recipe for one run, with ``changes``."""
    return validated(PoolConfig(**map_pool_study.RECIPE | {"seeds": [], "workers": 1} | changes))


def train(cfg: PoolConfig, staging: Path, progress: Any, start: float) -> PooledOneStepTrainer:
    """Train ``cfg``'s run (one mode, one seed) with its files in ``staging``."""
    torch.set_num_threads(1)
    env = MultiAgentEnv(grid_size=cfg.grid_shape(), max_steps=cfg.max_steps, seed=cfg.map_seed)
    trainer = PooledOneStepTrainer(env, cfg)
    train_into(trainer, staging, progress, start)
    return trainer


def held_out_record(
    trainer: PooledOneStepTrainer, label: str, episodes: int, start: float, trained: float
) -> dict[str, Any]:
    """A trained run's record, ``label`` naming it: its selected checkpoint and its exported
    pair tested on the held-out maps (``start``, ``trained``: its clock and training time)."""
    agents = tuple(load_policy(trainer.models_dir / f"{trainer.name}_agent_{a}.pt") for a in "AB")
    return {
        "mode": label,
        "seed": trainer.seed,
        "selected_env_steps": best_env_steps(trainer),
        "validation_success": best_selection(trainer),
        **held_out_results(agents, trainer.mode, episodes, trainer.cfg.max_steps),
        "seconds": {"training": trained, "total": time.perf_counter() - start},
    }


def train_and_test(
    mode: str, seed: int, staging: Path, episodes: int, changes: dict, progress: Any = None
) -> dict[str, Any]:
    """Train one (mode, seed) into ``staging`` and test its exported pair on the held-out maps."""
    start = time.perf_counter()
    cfg = recipe(mode=mode, seed=seed, **changes)
    trainer = train(cfg, staging, progress, start)
    return held_out_record(trainer, mode, episodes, start, time.perf_counter() - start)


def read_json(path: Path) -> dict | None:
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def summarise(runs: list[dict], episodes: int) -> dict[str, Any]:
    """The memory study's summary of these runs (paired with the map-pool study's memoryless
    runs by seed), described as what they are, with the GRU agents' success beside them."""
    cfg = recipe()
    results = gru_study.summarise(
        cfg, runs, beacon_homing(episodes, cfg.max_steps), gru_study.read_no_memory()
    )
    gru = read_json(gru_study.STUDY_DIR / "memory.json")
    results["description"] = (
        "agents with one step of memory (previous observation and move) trained on a pool of "
        "generated maps with the map-pool recipe, tested on held-out maps"
    )
    results["departures_from_the_assignment"] = map_pool_study.DEPARTURES | {
        "memory": "the previous observation (masked like the current one) and a one-hot of "
        "the previous move as inputs (27)"
    }
    results["gru_held_out"] = None if gru is None else gru["held_out"]["modes"]
    return results


def plot(path: Path, results: dict) -> None:
    """Held-out success at ε = 0.05 per mode: no memory (the map-pool study), one step of
    memory, GRU memory (the memory study); the explorers as lines."""
    no_memory = gru_study.read_no_memory()
    earlier = no_memory["held_out"]["modes"] if no_memory else {}
    gru = results.get("gru_held_out") or {}
    arms = [
        ("no memory", "#9aa9c2", {m: earlier[m]["eps"] for m in earlier}),
        ("one step", "#dd8452", {m: s["eps"] for m, s in results["held_out"]["modes"].items()}),
        ("GRU", "#4c72b0", {m: s["eps"] for m, s in gru.items()}),
    ]
    plot_held_out_bars(path, arms)


def plot_held_out_bars(path: Path, arms: list[tuple[str, str, dict]]) -> None:
    """Held-out success at ε = 0.05 per mode, a bar per arm (label, colour, mode -> its ``eps``
    statistics), the explorers of the map-pool study as lines; written to ``path``."""
    fig = Figure(figsize=(map_pool_study.FIGURE_WIDTH, 3.2), layout="constrained")
    ax = fig.subplots()
    map_pool_study.draw_success_bars(ax, list(MODES), arms)
    no_memory = gru_study.read_no_memory()
    if no_memory:
        map_pool_study.draw_reference_lines(ax, no_memory["held_out"]["heuristics"])
    label = f"success on held-out maps (ε = {CONDITIONS['eps']:g})"
    map_pool_study.save_bars(fig, ax, label, path)


def run_study(args: argparse.Namespace) -> dict:
    """Train and test every (mode, seed); install the outputs in ``output_dir`` whole."""
    episodes, changes = args.episodes_per_map, args.changes
    with staged_output(args.output_dir) as staging:
        jobs = [(m, s, staging, episodes, changes) for m in MODES for s in SEEDS[: args.num_seeds]]
        total = changes.get("total_steps", map_pool_study.RECIPE["total_steps"])
        runs = run_jobs(train_and_test, jobs, args.workers, ProgressLine(len(jobs), total))
        results = summarise(runs, episodes)
        write_json_atomic(staging / "unseen.json", results)
        plot(staging / "unseen.png", results)
        write_timing(staging / "timing.json", runs)
    return results


def train_lever(
    name: str, mode: str, seed: int, staging: Path, changes: dict, progress: Any = None
) -> dict[str, Any]:
    """One lever run, judged on the validation maps: the best checkpoint and the last
    evaluation, greedy and at ε = 0.05."""
    start = time.perf_counter()
    cfg = recipe(mode=mode, seed=seed, **LEVERS[name] | changes)
    trainer = train(cfg, staging / name, progress, start)
    last = trainer.checkpoints[-1]
    return {
        "lever": name,
        "mode": mode,
        "seed": seed,
        "best": best_selection(trainer),
        "last": {"greedy": last.greedy["success_rate"], "eps": last.eps["success_rate"]},
        "seconds": round(time.perf_counter() - start, 1),
    }


def summarise_levers(runs: list[dict]) -> dict[str, Any]:
    """Per lever and mode the validation success over the training seeds, and full −
    independent paired by seed (independent's recipe runs where the lever cannot change it)."""
    found = {(r["lever"], r["mode"], r["seed"]): r for r in runs}
    levers: dict[str, Any] = {}
    for name in LEVERS:
        source = {"independent": "recipe" if name in UNCHANGED_FOR_INDEPENDENT else name}
        entry: dict[str, Any] = {"changes": LEVERS[name], "meaning": LEVER_WORDS[name]}
        for mode in LEVER_MODES:
            mine = [found[(source.get(mode, name), mode, s)] for s in TRAINING_SEEDS]
            entry[mode] = {
                f"{when}_{c}": seed_statistics([r[when][c] for r in mine])
                for when in ("best", "last")
                for c in CONDITIONS
            }
        entry["full_minus_independent_best_eps"] = seed_statistics(
            [
                found[(name, "full", s)]["best"]["eps"]
                - found[(source["independent"], "independent", s)]["best"]["eps"]
                for s in TRAINING_SEEDS
            ]
        )
        levers[name] = entry
    return {
        "description": "levers for the partner's signal with one-step memory on the map pool, "
        "on training seeds, judged on the validation maps only",
        "training_seeds": list(TRAINING_SEEDS),
        "modes": list(LEVER_MODES),
        "levers": levers,
    }


def run_levers(args: argparse.Namespace) -> dict:
    """Train every lever's runs on the training seeds; write ``levers.json`` and the logs."""
    with staged_output(args.output_dir, subfolders=()) as staging:
        jobs = [
            (name, mode, seed, staging, args.changes)
            for name in LEVERS
            for mode in LEVER_MODES
            if not (mode == "independent" and name in UNCHANGED_FOR_INDEPENDENT)
            for seed in TRAINING_SEEDS
        ]
        total = args.changes.get("total_steps", map_pool_study.RECIPE["total_steps"])
        runs = run_jobs(train_lever, jobs, args.workers, ProgressLine(len(jobs), total))
        results = summarise_levers(runs)
        write_json_atomic(staging / "levers.json", results)
        timing = {f"{r['lever']}_{r['mode']}_seed{r['seed']}": r["seconds"] for r in runs}
        write_json_atomic(staging / "timing.json", timing)  # wall times: not a result
    return results


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    add = parser.add_argument
    add("--levers", action="store_true", help="run the levers on the training seeds instead")
    add("--workers", type=int, default=available_cores(), help="processes (1..64)")
    add("--output_dir", type=Path, default=None, help="folder written (default: results/...)")
    add("--episodes_per_map", type=int, default=EPISODES_PER_MAP, help="held-out test episodes")
    add("--num_seeds", type=int, default=len(SEEDS), help="seeds per mode, 1..5 (0, 1, ...)")
    add("--total_steps", type=int, default=None, help="smoke runs only: env steps per run")
    args = parser.parse_args(argv)
    default_dir = LEVERS_DIR if args.levers else STUDY_DIR
    if not 1 <= args.workers <= 64:
        parser.error(f"--workers must be in 1..64, got {args.workers}")
    if not 1 <= args.episodes_per_map <= 100_000:
        parser.error(f"--episodes_per_map must be in 1..100000, got {args.episodes_per_map}")
    if not 1 <= args.num_seeds <= len(SEEDS):
        parser.error(f"--num_seeds must be in 1..{len(SEEDS)}, got {args.num_seeds}")
    if args.total_steps is not None:
        if args.output_dir is None or args.output_dir.resolve() == default_dir.resolve():
            parser.error("--total_steps is for smoke runs: give another --output_dir")
        if args.total_steps < 1:
            parser.error(f"--total_steps must be an integer >= 1, got {args.total_steps}")
    args.output_dir = default_dir if args.output_dir is None else args.output_dir
    steps = {} if args.total_steps is None else {"total_steps": args.total_steps}
    smoke = {"eval_interval": max(1, args.total_steps // 2)} if steps else {}
    args.changes = steps | smoke
    return args


def run(args: argparse.Namespace) -> dict:
    """The levers' runs with ``--levers``, else the study's."""
    return run_levers(args) if args.levers else run_study(args)


def format_results(results: dict) -> str:
    """The levers' full − independent at ε, one line each, or the study's held-out table."""
    if "levers" not in results:
        return gru_study.format_table(results)
    return "\n".join(
        f"{name:<14} full - independent (validation, eps) "
        f"{entry['full_minus_independent_best_eps']['mean']:+.3f}"
        for name, entry in results["levers"].items()
    )


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    return study_main(argv, parse_args, run, format_results)


if __name__ == "__main__":
    run_command(main)
