"""The trained agents off their training map: map seeds 0–9 beside the baselines, and the
held-out maps (``HELD_OUT_MAP_SEEDS``, never used for any choice) with every model pair and
every baseline, including the memoryless heuristics. Part of ``python evaluate.py``
(``analysis.pipeline.evaluate_all`` calls :func:`evaluate_generalization` and
:func:`evaluate_held_out`)."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_SEED, PolicyFn, summarize
from vector_env import VectorMultiAgentEnv, generate_map

from analysis.baselines import POLICIES
from analysis.episodes import EvaluationSetting
from analysis.evaluator import (
    GENERALIZATION_MAP_SEEDS,
    MultiAgentEvaluator,
    PolicyFactory,
    experiment_evaluator,
)
from analysis.held_out import baselines_on_held_out  # never used for a choice
from analysis.map_sets import HELD_OUT_MAP_SEEDS
from analysis.runs import Experiment
from analysis.stats import seed_statistics

CONDITIONS = ("greedy", "eps")


def block_policy(factories: list[PolicyFactory], grid: np.ndarray, block_size: int) -> PolicyFn:
    """One policy over consecutive blocks of ``block_size`` copies, block k acting with
    ``factories[k]``: each run of consecutive blocks with the same factory is one policy
    ``factory(grid)`` called on its rows (a single policy if every block has the same)."""
    runs: list[tuple[PolicyFactory, int, int]] = []  # (factory, first row, end row)
    for k, factory in enumerate(factories):
        if runs and runs[-1][0] is factory:
            runs[-1] = (factory, runs[-1][1], (k + 1) * block_size)
        else:
            runs.append((factory, k * block_size, (k + 1) * block_size))
    if len(runs) == 1:
        return factories[0](grid)
    parts = [(factory(grid), slice(first, end)) for factory, first, end in runs]

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        outputs = [part(obs[rows], positions[rows]) for part, rows in parts]
        return np.concatenate([a for a, _ in outputs]), np.concatenate([m for _, m in outputs])

    return act


def one_policy_a_block(
    factories: list[PolicyFactory],
    grid: np.ndarray,
    block_size: int,
    policy: PolicyFn,
    env: VectorMultiAgentEnv,
    group: range,
) -> PolicyFn:
    """The ``wrap`` of ``MultiAgentEvaluator.run_blocks`` that lets block k of ``group``
    act with ``factories[k]`` instead of ``policy``."""
    return block_policy([factories[k] for k in group], grid, block_size)


def models_on_maps(
    experiment: Experiment, epsilon: float, map_seeds: tuple[int, ...], num_episodes: int
) -> dict[str, dict[str, np.ndarray]]:
    """Success of every model pair of ``experiment``, greedy and ε-greedy, on each of
    ``map_seeds`` (maps of the experiment's size and rules): ``{mode: {condition: (seeds,
    maps)}}``. Per map, every (mode, seed, condition) runs the same ``num_episodes`` test
    episodes in one batch (``MultiAgentEvaluator.run_blocks`` with one policy a block,
    :func:`one_policy_a_block`)."""
    evaluators = {
        (mode, seed): experiment_evaluator(experiment, epsilon, mode, seed)
        for mode, seeds in experiment.seeds.items()
        for seed in seeds
    }
    host = next(iter(evaluators.values()))
    blocks = [(pair, name) for pair in evaluators for name in CONDITIONS]
    policies = [evaluators[pair].policy_factory for pair, _ in blocks]
    epsilons = [host.conditions[name] for _, name in blocks]
    rules = (host.setting.reward_mode, host.setting.max_steps, host.setting.obs_window)
    rates = np.zeros((len(blocks), len(map_seeds)))
    for k, map_seed in enumerate(map_seeds):
        setting = EvaluationSetting(generate_map(experiment.grid.shape, map_seed), *rules)
        wrap = partial(one_policy_a_block, policies, setting.grid, num_episodes)
        runs = host.run_blocks(num_episodes, epsilons, wrap, setting=setting)
        rates[:, k] = [run.successes.mean() for run in runs]
    result: dict[str, dict[str, np.ndarray]] = {}
    for mode, seeds in experiment.seeds.items():
        result[mode] = {
            name: np.stack([rates[blocks.index(((mode, seed), name))] for seed in seeds])
            for name in CONDITIONS
        }
    return result


def evaluate_generalization(experiment: Experiment, num_episodes: int, epsilon: float) -> dict:
    """Every model pair of ``experiment`` on map seeds 0–9, beside the baseline policies on
    each map; per map and mode, seed statistics of the success rate."""
    size = experiment.grid.shape
    maps: dict[str, dict] = {}
    for map_seed in GENERALIZATION_MAP_SEEDS:
        grid = generate_map(size, map_seed)
        entry: dict[str, Any] = {"target": [int(v) for v in np.argwhere(grid == 2)[0]]}
        for name, policy in POLICIES.items():
            factory = partial(lambda g, make: make(g, EVAL_SEED), make=policy)
            evaluator = MultiAgentEvaluator(
                MultiAgentEnv(grid=grid, max_steps=int(experiment.settings["max_steps"])),
                policy_factory=factory,
            )
            entry[name] = summarize(evaluator.run(num_episodes, record=False))
        entry["modes"] = {}
        maps[str(map_seed)] = entry
    summary: dict[str, dict] = {}
    rates = models_on_maps(experiment, epsilon, GENERALIZATION_MAP_SEEDS, num_episodes)
    for mode, per_mode in rates.items():
        for k, map_seed in enumerate(maps):
            maps[map_seed]["modes"][mode] = {
                name: seed_statistics(per_mode[name][:, k].tolist()) for name in CONDITIONS
            }
        summary[mode] = {
            name: seed_statistics(per_mode[name].mean(axis=1).tolist()) for name in CONDITIONS
        }
    return {
        "trained_map_seed": experiment.settings["map_seed"],
        "episodes_per_map": num_episodes,
        "epsilon": epsilon,
        "map_seeds": list(GENERALIZATION_MAP_SEEDS),
        "maps": maps,
        "mean_over_maps": summary,
        "baselines_mean_over_maps": {
            name: float(np.mean([entry[name]["success_rate"] for entry in maps.values()]))
            for name in POLICIES
        },
    }


HEURISTICS = ("explorer", "sweep_explorer", "beacon_explorer")  # memoryless search, no map


def evaluate_held_out(experiment: Experiment, num_episodes: int, epsilon: float) -> dict:
    """Every baseline policy (greedy) and every model pair of ``experiment`` (greedy and
    ε-greedy) on ``HELD_OUT_MAP_SEEDS``, the same ``num_episodes`` start cells per map.

    ``success_rate[policy]``: a baseline's success per map, with its mean over maps and a
    95 % bootstrap CI over maps. ``modes[mode][condition]``: ``over_maps``, the mean over
    seeds on each map, with a CI over maps (comparable with the baselines');
    ``over_seeds``, each seed's mean over the maps, with a CI over seeds; and
    ``minus_<heuristic>``, the per-map difference to each memoryless heuristic (paired by
    map), with a CI over maps."""
    max_steps = int(experiment.settings["max_steps"])
    per_map = baselines_on_held_out(tuple(POLICIES), num_episodes, max_steps, experiment.grid.shape)
    modes: dict[str, dict] = {}
    for mode, per_mode in models_on_maps(
        experiment, epsilon, HELD_OUT_MAP_SEEDS, num_episodes
    ).items():
        modes[mode] = {}
        for name in CONDITIONS:
            rates = per_mode[name]  # (seeds, maps)
            map_means = rates.mean(axis=0)  # (maps,)
            modes[mode][name] = {
                "over_maps": seed_statistics(map_means.tolist()),
                "over_seeds": seed_statistics(rates.mean(axis=1).tolist()),
            } | {
                f"minus_{h}": seed_statistics((map_means - np.array(per_map[h])).tolist())
                for h in HEURISTICS
            }
    return {
        "map_seeds": list(HELD_OUT_MAP_SEEDS),
        "episodes_per_map": num_episodes,
        "epsilon": epsilon,
        "trained_map_seed": experiment.settings["map_seed"],
        "success_rate": {name: seed_statistics(rates) for name, rates in per_map.items()},
        "modes": modes,
        "note": "success_rate, over_maps and minus_*: ci95 and per_seed are over maps; "
        "over_seeds: over training seeds",
    }
