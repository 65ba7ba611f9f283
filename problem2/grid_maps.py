"""Maps of the two-agent grid world: cell codes, moves, generation and validation.

A map is an int64 array (H, W): 0 free, 1 obstacle, 2 the single target. Every free cell
must be able to reach the target.
"""

from __future__ import annotations

import numpy as np

FREE, OBSTACLE, TARGET, OFF_GRID = 0, 1, 2, -1
ACTION_NAMES = ("Up", "Down", "Left", "Right", "Stay")
NUM_ACTIONS = len(ACTION_NAMES)
ACTION_DELTAS = np.array([[-1, 0], [1, 0], [0, -1], [0, 1], [0, 0]])  # (d_row, d_col)
DEFAULT_MAP_SEED = 641  # the course default
MAX_MAP_ATTEMPTS = 1000


def check_grid_size(grid_size: tuple[int, int]) -> tuple[int, int]:
    """``grid_size`` as two Python ints (rows, cols), each at least 3, or ValueError."""
    try:
        rows, cols = (int(n) for n in grid_size)
        whole_numbers = (rows, cols) == tuple(grid_size)
    except (TypeError, ValueError):
        whole_numbers = False
    if not whole_numbers:
        raise ValueError(f"grid_size must be two integers (rows, cols), got {grid_size!r}")
    if rows < 3 or cols < 3:
        raise ValueError(f"grid must be at least 3×3, got {rows}×{cols}")
    return rows, cols


def reaches_target(maps: np.ndarray) -> np.ndarray:
    """Bool (M, H, W): the cells of maps (M, H, W) that reach the target by 4-neighbour
    moves around obstacles (a flood fill from the target, all maps at once)."""
    reached = maps == TARGET
    open_cells = maps != OBSTACLE
    while True:  # grow the set reachable from the target by one move per pass
        grown = reached.copy()
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown[:, :, 1:] |= reached[:, :, :-1]
        grown[:, :, :-1] |= reached[:, :, 1:]
        grown &= open_cells
        if np.array_equal(grown, reached):
            return reached
        reached = grown


def check_grid(grid: np.ndarray | list) -> np.ndarray:
    """Return ``grid`` as an int64 (H, W) array, or raise ValueError naming the problem:
    not rectangular, smaller than 3×3, values outside {0, 1, 2}, not exactly one target,
    fewer than two free cells, or a free cell that cannot reach the target."""
    try:
        array = np.array(grid)
    except ValueError as error:
        raise ValueError(f"map is not rectangular: {error}") from error
    if array.ndim != 2:
        raise ValueError(f"map must be a rectangular 2-D grid, got shape {array.shape}")
    if array.dtype.kind not in "iu":
        raise ValueError(f"map values must be integers, got dtype {array.dtype}")
    check_grid_size(array.shape)
    unknown = sorted(set(np.unique(array).tolist()) - {FREE, OBSTACLE, TARGET})
    if unknown:
        raise ValueError(f"map values must be 0 free, 1 obstacle or 2 target; found {unknown}")
    if (n_targets := int((array == TARGET).sum())) != 1:
        raise ValueError(f"map must contain exactly one target (2), found {n_targets}")
    if (array == FREE).sum() < 2:
        raise ValueError("map needs at least two free cells to place the agents")
    cut_off = np.argwhere((array == FREE) & ~reaches_target(array[None])[0])[:5].tolist()
    if cut_off:
        raise ValueError(f"map is not connected: free cells {cut_off} cannot reach the target")
    return array.astype(np.int64)


def generate_map(grid_size: tuple[int, int] = (10, 10), seed: int | None = None) -> np.ndarray:
    """Draw a map (H, W) int64 with ``np.random.default_rng(seed)``: 3–6 obstacles off the
    four corners, then one target on a free cell, redrawn until every free cell reaches the
    target. Raises ValueError if no such map turns up in ``MAX_MAP_ATTEMPTS`` draws."""
    rows, cols = check_grid_size(grid_size)
    rng = np.random.default_rng(seed)
    corners = [0, cols - 1, (rows - 1) * cols, rows * cols - 1]
    candidates = np.setdiff1d(np.arange(rows * cols), corners)
    for _ in range(MAX_MAP_ATTEMPTS):
        cells = np.zeros(rows * cols, dtype=np.int64)
        n_obstacles = min(int(rng.integers(3, 7)), len(candidates))
        cells[rng.choice(candidates, size=n_obstacles, replace=False)] = OBSTACLE
        cells[rng.choice(np.flatnonzero(cells == FREE))] = TARGET
        try:
            return check_grid(cells.reshape(rows, cols))
        except ValueError:
            continue
    raise ValueError(
        f"no connected {rows}×{cols} map with 3–6 obstacles found in "
        f"{MAX_MAP_ATTEMPTS} draws; use a larger grid"
    )


# ------------------------------------------------ checks of what callers hand the env
def is_integer(value: object) -> bool:
    """A Python or NumPy integer, not a bool."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def positive_int(value: object, name: str) -> int:
    """``value`` as an int if it is an integer >= 1; ValueError naming ``name`` otherwise."""
    if not is_integer(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_seed(seed: object, name: str = "seed") -> int | None:
    """``None`` or a non-negative integer (what NumPy's generators accept)."""
    if seed is not None and (not is_integer(seed) or seed < 0):
        raise ValueError(f"{name} must be None or a non-negative integer, got {seed!r}")
    return None if seed is None else int(seed)


def choose_map(grid_size: tuple[int, int], seed: int | None, grid: np.ndarray | None) -> np.ndarray:
    """The map the copies play, read-only: the checked ``grid``, or the map generated from
    ``seed`` at ``grid_size``."""
    one_map = generate_map(grid_size, seed) if grid is None else check_grid(grid)
    one_map.flags.writeable = False
    return one_map


def check_step(actions: object, messages: object, n_envs: int) -> tuple[np.ndarray, np.ndarray]:
    """``actions`` as an (N, 2) integer array in 0..4 and ``messages`` (N, 2) as float32
    clipped into [0, 1] (the channel is bounded); NaN, inf, a non-number or another shape
    raises ValueError."""
    actions = np.asarray(actions)
    if actions.shape != (n_envs, 2):
        raise ValueError(f"actions must have shape ({n_envs}, 2), got {actions.shape}")
    if actions.dtype.kind not in "iu":
        raise ValueError(f"actions must be integers 0..4, got dtype {actions.dtype}")
    if actions.min() < 0 or actions.max() >= NUM_ACTIONS:
        bad = np.unique(actions[(actions < 0) | (actions >= NUM_ACTIONS)])
        raise ValueError(f"actions must be in 0..4 (Up, Down, Left, Right, Stay), got {bad}")
    messages = np.asarray(messages)
    if messages.shape != (n_envs, 2) or messages.dtype.kind not in "fiub":
        raise ValueError(
            f"messages must be numbers of shape ({n_envs}, 2), "
            f"got {messages.dtype} {messages.shape}"
        )
    if not np.isfinite(messages).all():
        raise ValueError(f"messages must be finite numbers (clipped into [0, 1]), got {messages}")
    return actions, np.clip(messages, 0.0, 1.0).astype(np.float32, copy=False)  # clip copies
