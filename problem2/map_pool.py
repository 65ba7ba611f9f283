"""Pools of procedurally generated maps, for agents that must not memorise one map.

Every map comes from :func:`grid_maps.generate_map` with its own seed. Three disjoint
ranges of map seeds:

* training maps: seeds ``TRAINING_FIRST_SEED + i`` (a new one drawn at each episode start);
* validation maps: seeds ``VALIDATION_FIRST_SEED + i`` (checkpoint selection);
* held-out test maps: ``HELD_OUT_MAP_SEEDS`` = 1000..1039, the maps on which the
  baselines are also tested; no setting or checkpoint is chosen on them.

:func:`held_out_success` is the one test on the held-out maps: trained agents
(``map_pool_study.py``) and the baseline policies (:func:`baselines_on_held_out`, used by
the study and by ``evaluate.py``'s ``analysis_generalization``) all run through it.

The default map (seed 641) is in none of the pools. A pool also drops any generated map
that equals a held-out map or the default map cell for cell (none does for the pool
sizes used here; a test checks it), so "disjoint" holds for the maps, not only the seeds.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from baselines import POLICIES
from grid_maps import DEFAULT_MAP_SEED, generate_map
from multi_agent_env import VectorMultiAgentEnv
from rollout import EVAL_SEED, PolicyFn, evaluate_policy

HELD_OUT_MAP_SEEDS = tuple(range(1000, 1040))  # also the evaluator's held-out maps
TRAINING_FIRST_SEED = 100_000
VALIDATION_FIRST_SEED = 200_000
MAX_POOL_SIZE = VALIDATION_FIRST_SEED - TRAINING_FIRST_SEED  # the ranges never overlap


@lru_cache(maxsize=8)
def _excluded_maps(grid_size: tuple[int, int]) -> frozenset[bytes]:
    seeds = (*HELD_OUT_MAP_SEEDS, DEFAULT_MAP_SEED)
    return frozenset(generate_map(grid_size, seed).tobytes() for seed in seeds)


@lru_cache(maxsize=8)
def _pool(first_seed: int, size: int, grid_size: tuple[int, int]) -> np.ndarray:
    if not isinstance(size, int) or not 1 <= size <= MAX_POOL_SIZE:
        raise ValueError(f"a map pool holds 1..{MAX_POOL_SIZE} maps, got {size!r}")
    excluded = _excluded_maps(grid_size)
    maps, seed = [], first_seed
    while len(maps) < size:
        grid = generate_map(grid_size, seed)
        if grid.tobytes() not in excluded:
            maps.append(grid)
        seed += 1
    pool = np.stack(maps)
    pool.flags.writeable = False
    return pool


def training_maps(size: int, grid_size: tuple[int, int] = (10, 10)) -> np.ndarray:
    """The first ``size`` training maps (size, H, W) int64 (read-only, cached)."""
    return _pool(TRAINING_FIRST_SEED, size, tuple(grid_size))


def validation_maps(size: int, grid_size: tuple[int, int] = (10, 10)) -> np.ndarray:
    """The first ``size`` validation maps (size, H, W) int64 (read-only, cached)."""
    return _pool(VALIDATION_FIRST_SEED, size, tuple(grid_size))


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
            episodes, max_steps, {"greedy": 0.0}, grid_size,
        )["greedy"]
        for name in names
    }  # fmt: skip
