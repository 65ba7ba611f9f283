"""Levers that might make a receiver listen, tried on training seeds (never the study's).

Each setting trains GRU agents of the memory study's recipe (``study.RECIPE``) in the
modes that hear a message, on training seeds 100 and up, and is judged on the validation
maps only (the held-out maps are never used for a choice): the best checkpoint's and the
last evaluation's success, greedy and at ε = 0.05. Settings (``SETTINGS``): the recipe, DIAL
noise σ = 2 on the message logit (the DIAL paper's; 1 in the recipe), potential-based
shaping by the agents' distance, a positive-listening loss, a positive-signalling loss,
runs twice as long, and a curriculum (half of the first episodes start with one agent on
the target, a share that falls to none at mid-run).

``python -m studies.memory.levers`` writes ``results/studies/memory_levers/levers.json``
(and the runs' training logs beside it) and prints one line per setting.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import time
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.stats import seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from multi_agent_env import MultiAgentEnv
from settings import SettingError, available_cores, usage, validated

from studies.memory.learner import Levers, RecurrentTrainer
from studies.memory.study import RECIPE, RESULTS
from studies.pool_training import PoolConfig
from studies.staging import (
    best_env_steps,
    best_selection,
    check_field,
    run_command,
    staged_output,
    train_into,
)

OUTPUT_DIR = RESULTS / "memory_levers"
SETTINGS: dict[str, dict[str, Any]] = {
    "recipe": {},
    "dial_noise_2": {"comm_noise": 2.0},
    "distance_shaping": {"levers": Levers(distance_potential=1.0)},
    "listening_loss": {"levers": Levers(listening=0.1)},
    "signalling_loss": {"levers": Levers(signalling=0.1)},
    "twice_as_long": {"total_steps": 2 * RECIPE["total_steps"]},
    "curriculum": {"levers": Levers(curriculum=0.5)},
}
TRAINING_SEEDS = (100, 101)
LEVER_MODES = ("full",)


def train_setting(
    cfg: PoolConfig, setting: str, mode: str, seed: int, folder: Path, progress: Any = None
) -> dict[str, Any]:
    """Train one (setting, mode, seed); its validation results."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    changes = dict(SETTINGS[setting])
    levers = changes.pop("levers", Levers())
    run_cfg = dataclasses.replace(cfg, seed=seed, seeds=[], workers=1, **changes)
    env = MultiAgentEnv(grid_size=cfg.grid_shape(), max_steps=cfg.max_steps, seed=cfg.map_seed)
    trainer = RecurrentTrainer(env, run_cfg, mode, levers)
    log = train_into(trainer, folder / setting, progress, start, f"{setting}/{trainer.name}")
    shutil.rmtree(trainer.models_dir, ignore_errors=True)  # judged by validation only
    last = log[-1]
    return {
        "setting": setting,
        "mode": mode,
        "seed": seed,
        "best": best_selection(trainer),
        "best_env_steps": best_env_steps(trainer),
        "final": {"greedy": last["eval_success_greedy"], "eps": last["eval_success_eps"]},
        "seconds": round(time.perf_counter() - start, 1),
    }


def summarise(runs: list[dict]) -> dict[str, Any]:
    settings: dict[str, Any] = {}
    for run in runs:
        entry = settings.setdefault(run["setting"], {}).setdefault(run["mode"], [])
        entry.append(run)
    return {
        "description": "listening levers on training seeds, judged on the validation maps",
        "settings": {
            name: {
                "changes": {
                    k: (dataclasses.asdict(v) if isinstance(v, Levers) else v)
                    for k, v in SETTINGS[name].items()
                },
                "modes": {
                    mode: {
                        "seeds": [r["seed"] for r in mine],
                        **{
                            f"{when}_{c}": seed_statistics([r[when][c] for r in mine])
                            for when in ("best", "final")
                            for c in ("greedy", "eps")
                        },
                    }
                    for mode, mine in by_mode.items()
                },
            }
            for name, by_mode in settings.items()
        },
        "runs": [{k: v for k, v in r.items() if k != "seconds"} for r in runs],
    }


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--setting", default="all", help="all, or some of " + ", ".join(SETTINGS))
    parser.add_argument("--workers", type=int, default=available_cores())
    parser.add_argument("--output_dir", "--output-dir", type=Path, default=OUTPUT_DIR)
    args = parser.parse_args(argv)
    names = list(SETTINGS) if args.setting == "all" else args.setting.split(",")
    unknown = [n for n in names if n not in SETTINGS]
    if unknown:
        parser.error(
            f"--setting: unknown {', '.join(unknown)}; use all or some of {', '.join(SETTINGS)}"
        )
    try:
        cfg = validated(PoolConfig(**RECIPE | {"seeds": [], "workers": args.workers}))
        check_field("workers", args.workers)
    except SettingError as error:
        parser.error(usage(error))
    steps = max(SETTINGS[n].get("total_steps", cfg.total_steps) for n in names)
    with staged_output(args.output_dir, subfolders=()) as staging:  # installed whole
        jobs = [(cfg, n, m, s, staging) for n in names for m in LEVER_MODES for s in TRAINING_SEEDS]
        runs = run_jobs(train_setting, jobs, args.workers, ProgressLine(len(jobs), steps))
        results = summarise(runs)
        write_json_atomic(staging / "levers.json", results)
    for name, entry in results["settings"].items():
        for mode, stats in entry["modes"].items():
            print(
                f"{name:<18} {mode:<6} best eps {stats['best_eps']['mean']:.3f} "
                f"final eps {stats['final_eps']['mean']:.3f} "
                f"(seeds {np.round(stats['final_eps']['per_seed'], 3).tolist()})"
            )
    return results


if __name__ == "__main__":
    run_command(main)
