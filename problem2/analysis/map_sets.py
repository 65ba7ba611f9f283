"""Pools of generated maps, for agents that must not memorise one map (the map-pool study,
the memory study) and for the evaluator's test on maps never trained on.

Three disjoint ranges of map seeds: training maps ``TRAINING_FIRST_SEED + i`` (a new one drawn
at each episode start), validation maps ``VALIDATION_FIRST_SEED + i`` (checkpoint selection),
and the held-out test maps ``HELD_OUT_MAP_SEEDS``, on which no setting or checkpoint is chosen
(``analysis/held_out.py`` tests on them). A pool also drops any generated map that equals a
held-out map or the default map cell for cell, so "disjoint" holds for the maps, not only the
seeds.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from vector_env import DEFAULT_MAP_SEED, generate_map

HELD_OUT_MAP_SEEDS = tuple(range(1000, 1040))  # also the evaluator's held-out maps
TRAINING_FIRST_SEED = 100_000
VALIDATION_FIRST_SEED = 200_000
MAX_POOL_SIZE = VALIDATION_FIRST_SEED - TRAINING_FIRST_SEED  # the ranges never overlap


@lru_cache(maxsize=8)
def _pool(first_seed: int, size: int, grid_size: tuple[int, int]) -> np.ndarray:
    if not isinstance(size, int) or not 1 <= size <= MAX_POOL_SIZE:
        raise ValueError(f"a map pool holds 1..{MAX_POOL_SIZE} maps, got {size!r}")
    seeds = (*HELD_OUT_MAP_SEEDS, DEFAULT_MAP_SEED)
    excluded = {generate_map(grid_size, seed).tobytes() for seed in seeds}
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
