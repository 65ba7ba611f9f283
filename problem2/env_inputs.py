"""Checks of what callers hand to ``vector_env.VectorMultiAgentEnv``.

Each function returns its input in the form the environment uses, or raises ValueError
naming the input and the values it may take.
"""

from __future__ import annotations

import numpy as np
from grid_maps import NUM_ACTIONS, check_grid, check_grid_stack, generate_map


def is_integer(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def positive_int(value: object, name: str) -> int:
    if not is_integer(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_seed(seed: object, name: str = "seed") -> int | None:
    """``None`` or a non-negative integer (what NumPy's generators accept)."""
    if seed is not None and (not is_integer(seed) or seed < 0):
        raise ValueError(f"{name} must be None or a non-negative integer, got {seed!r}")
    return None if seed is None else int(seed)


def check_choice(value: object, choices: tuple[str, ...], name: str) -> str:
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")
    return value


def check_obs_window(obs_window: object) -> int:
    if not is_integer(obs_window) or obs_window < 3 or obs_window % 2 == 0:
        raise ValueError(f"obs_window must be an odd integer >= 3, got {obs_window!r}")
    return int(obs_window)


def choose_maps(
    n_envs: int,
    grid_size: tuple[int, int],
    seed: int | None,
    grid: np.ndarray | None,
    grids: np.ndarray | None,
    map_pool: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The maps (M, H, W) the copies play and, if M = 1, that map (H, W), else None.

    At most one of ``grid``, ``grids`` (one map per copy) and ``map_pool`` may be given;
    each is checked. With none, the map is generated from ``seed`` at ``grid_size``.
    """
    if sum(option is not None for option in (grid, grids, map_pool)) > 1:
        raise ValueError("give at most one of grid, grids and map_pool")
    if grids is not None or map_pool is not None:
        stacked = grids if grids is not None else map_pool
        all_maps = check_grid_stack(stacked, "grids" if grids is not None else "map_pool")
        if grids is not None and len(all_maps) != n_envs:
            raise ValueError(f"grids must hold n_envs = {n_envs} maps, got {len(grids)}")
        return all_maps, all_maps[0] if len(all_maps) == 1 else None  # else: map_indices
    one_map = generate_map(grid_size, seed) if grid is None else check_grid(grid)
    one_map.flags.writeable = False
    return one_map[None], one_map


def check_cell_array(positions: object, n_envs: int, name: str) -> np.ndarray:
    """``positions`` as an (N, 2, 2) integer array of (row, col) cells (not yet checked
    against the map), or ValueError."""
    positions = np.asarray(positions)
    if positions.shape != (n_envs, 2, 2) or positions.dtype.kind not in "iu":
        raise ValueError(
            f"{name} must be integers of shape ({n_envs}, 2, 2), "
            f"got {positions.dtype} {positions.shape}"
        )
    return positions


def check_action_values(actions: object) -> np.ndarray:
    """``actions`` of any shape as an integer array in 0..4, or ValueError."""
    actions = np.asarray(actions)
    if actions.dtype.kind not in "iu" or (actions < 0).any() or (actions >= NUM_ACTIONS).any():
        raise ValueError(f"actions must be integers in 0..{NUM_ACTIONS - 1}, got {actions}")
    return actions


def check_joint_actions(actions: np.ndarray, n_envs: int) -> np.ndarray:
    """``actions`` as an (N, 2) integer array in 0..4, or ValueError."""
    actions = np.asarray(actions)
    if actions.shape != (n_envs, 2):
        raise ValueError(f"actions must have shape ({n_envs}, 2), got {actions.shape}")
    if actions.dtype.kind not in "iu":
        raise ValueError(f"actions must be integers 0..4, got dtype {actions.dtype}")
    if actions.min() < 0 or actions.max() >= NUM_ACTIONS:
        bad = np.unique(actions[(actions < 0) | (actions >= NUM_ACTIONS)])
        raise ValueError(f"actions must be in 0..4 (Up, Down, Left, Right, Stay), got {bad}")
    return actions


def check_messages(messages: np.ndarray, n_envs: int) -> np.ndarray:
    """``messages`` (N, 2) as float32 clipped into [0, 1] (the channel is bounded); NaN,
    inf, a non-number or another shape raises ValueError."""
    messages = np.asarray(messages)
    if messages.shape != (n_envs, 2) or messages.dtype.kind not in "fiub":
        raise ValueError(
            f"messages must be numbers of shape ({n_envs}, 2), "
            f"got {messages.dtype} {messages.shape}"
        )
    if not np.isfinite(messages).all():
        raise ValueError(f"messages must be finite numbers (clipped into [0, 1]), got {messages}")
    return np.clip(messages, 0.0, 1.0).astype(np.float32, copy=False)  # clip made a copy
