"""The memory panel: does one step of memory change what the channels are worth?

    python -m studies.one_step.panel --train     # train every map's batch, then summarise
    python -m studies.one_step.panel             # summarise the trained batches
    python -m studies.one_step.panel --maps 4 --total_steps 30000 --workers 1 \\
        --output_dir /tmp/memory_panel --train   # a smoke run (never into the default folder)

The map panel's 12 maps (``studies.panel.PANEL_MAP_SEEDS``) x 4 modes x training seeds
641-645, each map's batch trained with the main experiment's recipe (``TrainConfig``
defaults) by :class:`agents.OneStepMemoryTrainer` into ``map<K>/{agent_models,
training_logs}``. Every exported pair is tested on the panel's protocol: the 1000 test
episodes whose start cells ``rollout.EVAL_SEED`` draws, greedy and at ε = 0.05 with the
panel's exploration draws (``analysis.episodes.explore_by_step``: one draw per episode, step
and agent), the move actually made fed back as ``prev_action``. The memoryless agents'
per-seed success is read from the map panel's ``panel.json`` (the same episodes and draws),
or recomputed from its models where the panel has no entry for the map.

Outputs (atomic): ``memory_panel.json``, ``memory_panel.csv``, ``memory_panel.png``
(``panel_outputs.py``) and ``timing.json`` (the only file that differs between reruns).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
import train
from analysis.baselines import int_list
from analysis.episodes import explore_by_step, model_policy
from analysis.stats import BOOTSTRAP_RESAMPLES, CONFIDENCE, mode_contrasts, seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from rollout import EVAL_EPSILON, EVAL_SEED, PolicyFn, run_episodes
from settings import TRAINABLE_MODES, TrainConfig, available_cores
from vector_env import VectorMultiAgentEnv

from studies.memory.agents import memory_policy
from studies.one_step.agents import OneStepMemoryTrainer
from studies.one_step.panel_outputs import format_table, plot_panel, write_csv
from studies.panel import EFFECT_WORDS, EFFECTS, PANEL_DIR, PANEL_MAP_SEEDS
from studies.staging import run_command

MEMORY_PANEL_DIR = PANEL_DIR.parent / "memory_panel"
MODES = TRAINABLE_MODES
SEEDS = tuple(range(641, 646))
CONDITIONS = {"greedy": 0.0, "eps": EVAL_EPSILON}


def train_map(map_seed: int, output_dir: Path, workers: int, total_steps: int | None) -> None:
    """Train map ``map_seed``'s batch (4 modes x 5 seeds) into ``output_dir/map<K>``."""
    settings: dict[str, Any] = dict(
        mode=",".join(MODES),
        map_seed=map_seed,
        seed=SEEDS[0],
        num_seeds=len(SEEDS),
        overwrite=True,
        output_dir=str(output_dir / f"map{map_seed}"),
        workers=workers,
    )
    if total_steps is not None:
        settings["total_steps"] = total_steps
    train.main(cfg=TrainConfig(**settings), trainer_class=OneStepMemoryTrainer)


def exploration(env: VectorMultiAgentEnv, epsilon: float, seed: int = EVAL_SEED) -> PolicyFn:
    """The panel's exploration draws on ``env``'s copies (one test episode each): returns
    actions (N, 2), the random move where the agent explores now, −1 elsewhere."""
    n = env.n_envs
    nothing = (np.full((n, 2), -1), np.zeros((n, 2), np.float32))
    return explore_by_step(lambda obs, positions: nothing, env, np.full(n, epsilon), n, seed)


def memory_pair_policy(
    agents: tuple[torch.nn.Module, torch.nn.Module], env: VectorMultiAgentEnv, epsilon: float
) -> PolicyFn:
    """Two memory-contract agents on ``env`` (``studies.memory.agents.memory_policy``) with
    the panel's exploration draws: the move made (explored or greedy) is fed back as the
    next ``prev_action``."""
    return memory_policy(agents, env, draws=exploration(env, epsilon))


def pair_policy(agents: tuple, env: VectorMultiAgentEnv, epsilon: float) -> PolicyFn:
    """An exported pair on the panel's protocol: memory-contract agents (``initial_state``)
    with the move made fed back, memoryless ones (``model(obs) -> (q, message)``) through
    ``model_policy``; both with the panel's exploration draws."""
    if hasattr(agents[0], "initial_state"):
        return memory_pair_policy(agents, env, epsilon)
    n = env.n_envs
    return explore_by_step(model_policy(*agents), env, np.full(n, epsilon), n, EVAL_SEED)


def successes(
    models_dir: Path,
    mode: str,
    seed: int,
    grid: np.ndarray,
    max_steps: int,
    episodes: int,
    env_class: type[VectorMultiAgentEnv] = VectorMultiAgentEnv,
) -> dict[str, np.ndarray]:
    """Per-episode success (E,) of one exported pair per condition; memory-contract files
    (``initial_state``) or memoryless ones (``model(obs) -> (q, message)``), played in
    ``env_class`` (a study's environment that changes an input, as in training)."""
    agents = tuple(
        torch.jit.load(str(models_dir / f"{mode}_seed{seed}_agent_{a}.pt")) for a in "AB"
    )
    result = {}
    for condition, epsilon in CONDITIONS.items():
        env = env_class(episodes, grid=grid, max_steps=max_steps)
        policy = pair_policy(agents, env, epsilon)
        result[condition] = run_episodes(env, policy, episodes, seed=EVAL_SEED).successes
    return result


def read_batch(models_dir: Path) -> tuple[np.ndarray, int]:
    """The map (H, W) and time limit of a trained batch (its map.json, hyperparameters)."""
    grid = json.loads((models_dir / "map.json").read_text(encoding="utf-8"))["grid"]
    settings = json.loads((models_dir / "hyperparameters.json").read_text(encoding="utf-8"))
    return np.asarray(grid), int(settings.get("max_steps", 50))


def memoryless_rates(
    map_seed: int, panel_dir: Path, grid: np.ndarray, max_steps: int, episodes: int
) -> tuple[dict[str, dict[str, list[float]]], str]:
    """Per mode and condition the memoryless success rate of seeds 641-645 on map
    ``map_seed``: from ``panel.json`` if it holds the map on the same number of episodes,
    else recomputed from the panel's models. Returns the rates and their source."""
    panel_file = panel_dir / "panel.json"
    if panel_file.is_file():
        panel = json.loads(panel_file.read_text(encoding="utf-8"))
        entry = panel["maps"].get(str(map_seed))
        same = panel["protocol"]["episodes_per_seed"] == episodes
        if entry and same and all(entry["seeds"].get(m) == list(SEEDS) for m in MODES):
            rates = {m: {c: entry["success"][m][c]["per_seed"] for c in CONDITIONS} for m in MODES}
            return rates, "panel.json"
    models_dir = panel_dir / f"map{map_seed}" / "agent_models"
    rates = {m: {c: [] for c in CONDITIONS} for m in MODES}
    for mode in MODES:
        for seed in SEEDS:
            for c, s in successes(models_dir, mode, seed, grid, max_steps, episodes).items():
                rates[mode][c].append(float(s.mean()))
    return rates, "recomputed from the map panel's models"


def paired(values: list[float]) -> dict[str, Any]:
    """:func:`seed_statistics` of per-seed differences, with ``established`` (CI excludes 0)."""
    stats = seed_statistics(values)
    low, high = stats["ci95"]
    return stats | {"established": bool(low > 0 or high < 0)}


def contrast(rates: dict[str, list[float]], coefficients: dict[str, float]) -> np.ndarray:
    """Per-seed value (S,) of a contrast of the modes' per-seed rates."""
    return sum(c * np.asarray(rates[m], dtype=np.float64) for m, c in coefficients.items())


def map_entry(
    map_seed: int,
    memory: dict[str, dict[str, np.ndarray]],
    memoryless: dict[str, dict[str, list[float]]],
    beacon: float | None,
) -> dict[str, Any]:
    """The JSON entry of one map; ``memory[mode][condition]`` (S, E) per-episode success."""
    entry: dict[str, Any] = {"map_seed": map_seed, "seeds": list(SEEDS)}
    entry |= {"beacon_explorer_success": beacon, "conditions": {}}
    for condition in CONDITIONS:
        with_memory = {
            m: memory[m][condition].mean(axis=1, dtype=np.float64).tolist() for m in MODES
        }
        without = {m: memoryless[m][condition] for m in MODES}
        cells = {
            m: {
                "memoryless": seed_statistics(without[m]),
                "memory": seed_statistics(with_memory[m]),
            }
            for m in MODES
        }
        effect = {
            m: paired([a - b for a, b in zip(with_memory[m], without[m], strict=True)])
            for m in MODES
        }
        channels = mode_contrasts({m: memory[m][condition] for m in MODES}, EFFECTS)
        interaction = {
            name: paired((contrast(with_memory, c) - contrast(without, c)).tolist())
            for name, c in EFFECTS.items()
        }
        entry["conditions"][condition] = {
            "success": cells,
            "memory_effect": effect,
            "channel_effects_with_memory": channels,
            "channel_effects_memory_interaction": interaction,
        }
    return entry


def evaluate_map(
    map_seed: int, output_dir: str, panel_dir: str, episodes: int, progress: Any = None
) -> tuple[dict, float]:
    """The memory panel's entry of one map and its seconds (a ``batch.plumbing.run_jobs`` job)."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    models_dir = Path(output_dir) / f"map{map_seed}" / "agent_models"
    grid, max_steps = read_batch(models_dir)
    memory = {m: {c: [] for c in CONDITIONS} for m in MODES}
    for mode in MODES:
        for seed in SEEDS:
            for c, s in successes(models_dir, mode, seed, grid, max_steps, episodes).items():
                memory[mode][c].append(s)
    memory = {
        m: {c: np.stack(v).astype(np.float32) for c, v in d.items()} for m, d in memory.items()
    }
    memoryless, source = memoryless_rates(map_seed, Path(panel_dir), grid, max_steps, episodes)
    entry = map_entry(map_seed, memory, memoryless, beacon_success(Path(panel_dir), map_seed))
    return entry | {"memoryless_source": source}, time.perf_counter() - start


def beacon_success(panel_dir: Path, map_seed: int) -> float | None:
    """The beacon explorer's greedy success on the map, from the map panel's references."""
    panel_file = panel_dir / "panel.json"
    if not panel_file.is_file():
        return None
    entry = json.loads(panel_file.read_text(encoding="utf-8"))["maps"].get(str(map_seed), {})
    beacon = entry.get("references", {}).get("beacon_explorer")
    return None if beacon is None else float(beacon["success_rate"])


def summarise(entries: list[dict], episodes: int) -> dict[str, Any]:
    """The study's JSON (no wall times): protocol and the maps."""
    protocol = {
        "maps": [e["map_seed"] for e in entries],
        "modes": list(MODES),
        "training_seeds": list(SEEDS),
        "recipe": "the main experiment's (TrainConfig defaults) with one-step memory: input "
        "[patch, previous observation (masked like the current one), one-hot of the agent's "
        "previous move, message, distance] (27), zeros at an episode start",
        "evaluation_seed": EVAL_SEED,
        "episodes_per_seed": episodes,
        "conditions": CONDITIONS,
        "exploration": "the map panel's draws (analysis.episodes.explore_by_step), the move "
        "made fed back to the memory agent",
        "success": "both agents on the target on the same step within max_steps",
        "cells": "message x distance x memory: the modes independent (neither channel), comm "
        "(message), distance (distance), full (both), each memoryless (the map panel) and "
        "with one-step memory; mean over seeds with a 95 % bootstrap CI over seeds",
        "memory_effect": "memory - memoryless of the same mode, paired by training seed "
        "(same seed number), seed_statistics of the 5 differences; established: the "
        "interval excludes 0",
        "channel_effects_with_memory": "analysis.stats.mode_contrasts of the memory agents "
        "(test episodes resampled once for all modes, seeds within each mode), as the map "
        "panel's effects",
        "channel_effects_memory_interaction": "effect with memory - effect without, per "
        "training seed (same seed number in every mode), seed_statistics of the 5 values",
        "effects": {n: {"coefficients": EFFECTS[n], "meaning": EFFECT_WORDS[n]} for n in EFFECTS},
        "bootstrap_resamples": BOOTSTRAP_RESAMPLES,
        "confidence": CONFIDENCE,
        "beacon_explorer": "the map panel's reference (greedy success), if it has the map",
    }
    return {"protocol": protocol, "maps": {str(e["map_seed"]): e for e in entries}}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    add = parser.add_argument
    add("--maps", type=int_list, default=list(PANEL_MAP_SEEDS), help="map seeds, e.g. 641,4")
    add("--train", action="store_true", help="train the maps' batches first")
    add("--num_episodes", type=int, default=1000, help="test episodes per seed (1..5000)")
    add("--workers", type=int, default=min(2, available_cores()), help="processes (1..64)")
    add("--total_steps", type=int, default=None, help="smoke tests only: env steps per run")
    add("--output_dir", type=Path, default=MEMORY_PANEL_DIR, help="the memory panel's folder")
    add("--panel_dir", type=Path, default=PANEL_DIR, help="the memoryless map panel's folder")
    args = parser.parse_args(argv)
    if not args.maps or min(args.maps) < 0 or len(set(args.maps)) != len(args.maps):
        parser.error(f"--maps must be distinct non-negative integers, got {args.maps}")
    if not 1 <= args.num_episodes <= 5000:
        parser.error(f"--num_episodes must be in 1..5000, got {args.num_episodes}")
    if not 1 <= args.workers <= 64:
        parser.error(f"--workers must be in 1..64, got {args.workers}")
    default_dir = args.output_dir.resolve() == MEMORY_PANEL_DIR.resolve()
    if args.total_steps is not None and (default_dir or not args.train):
        parser.error("--total_steps is for smoke runs: give --train and another --output_dir")
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Train (with ``--train``) and evaluate the maps, then write the study's files."""
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    args = parse_args(argv)
    seconds: dict[str, float] = {}
    if args.train:
        for map_seed in args.maps:
            start = time.perf_counter()
            train_map(map_seed, args.output_dir, args.workers, args.total_steps)
            seconds[f"train_map{map_seed}"] = round(time.perf_counter() - start, 1)
    jobs = [(m, str(args.output_dir), str(args.panel_dir), args.num_episodes) for m in args.maps]
    done = run_jobs(evaluate_map, jobs, args.workers, ProgressLine(len(jobs), 0))
    results = summarise([entry for entry, _ in done], args.num_episodes)
    write_json_atomic(args.output_dir / "memory_panel.json", results)
    write_csv(args.output_dir / "memory_panel.csv", results)
    plot_panel(args.output_dir / "memory_panel.png", results)
    seconds |= {f"evaluate_map{m}": round(s, 1) for (m, *_), (_, s) in zip(jobs, done, strict=True)}
    write_json_atomic(args.output_dir / "timing.json", {"seconds": seconds})
    print(format_table(results))
    print(f"wrote {args.output_dir} (seconds: {seconds})")
    return results


if __name__ == "__main__":
    run_command(main)
