"""Success on the 40 held-out maps (``vector_env.HELD_OUT_MAP_SEEDS``): the one test there.

Trained agents (``studies/map_pool_study.py``) and the baseline policies
(:func:`baselines_on_held_out`, used by the study and by ``analysis/generalization.py``) all
run through :func:`held_out_success`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from rollout import EVAL_SEED, PolicyFn, evaluate_policy
from vector_env import VectorMultiAgentEnv, generate_map

from analysis.baselines import POLICIES
from analysis.map_sets import HELD_OUT_MAP_SEEDS


@lru_cache(maxsize=8)
def held_out_maps(grid_size: tuple[int, int] = (10, 10)) -> np.ndarray:
    """The 40 held-out test maps (40, H, W), in the order of ``HELD_OUT_MAP_SEEDS`` (read-only,
    cached)."""
    maps = np.stack([generate_map(tuple(grid_size), seed) for seed in HELD_OUT_MAP_SEEDS])
    maps.flags.writeable = False
    return maps


def held_out_success(
    make_policy: Callable[[np.ndarray, int, float], PolicyFn],
    episodes: int,
    max_steps: int,
    conditions: dict[str, float],
    grid_size: tuple[int, int] = (10, 10),
) -> dict[str, list[float]]:
    """Success rate per held-out map (40,) for each condition: ``make_policy(grid, map_seed,
    epsilon)`` returns a policy. Every map plays the same ``episodes`` start cells, drawn
    from ``EVAL_SEED`` (the evaluator's test episodes); policies seed their own streams with
    ``EVAL_SEED + map seed``."""
    rates: dict[str, list[float]] = {label: [] for label in conditions}
    for map_seed, grid in zip(HELD_OUT_MAP_SEEDS, held_out_maps(grid_size), strict=True):
        env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
        for label, epsilon in conditions.items():
            summary = evaluate_policy(env, make_policy(grid, map_seed, epsilon), episodes)
            rates[label].append(summary["success_rate"])
    return rates


def baselines_on_held_out(
    names: tuple[str, ...], episodes: int, max_steps: int, grid_size: tuple[int, int] = (10, 10)
) -> dict[str, list[float]]:
    """Success rate per held-out map (40,) of each baseline policy of ``names`` (keys of
    ``baselines.POLICIES``), greedy: :func:`held_out_success` of each."""
    return {
        name: held_out_success(
            lambda grid, map_seed, epsilon, make=POLICIES[name]: make(grid, EVAL_SEED + map_seed),
            episodes,
            max_steps,
            {"greedy": 0.0},
            grid_size,
        )["greedy"]
        for name in names
    }
