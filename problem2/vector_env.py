"""The maps, dynamics, observations and rewards of Problem 2, for N copies at once.

The maps: cell codes, moves, generation and validation (:func:`generate_map`), and the
checks of what callers hand the environment.

``VectorMultiAgentEnv`` is the only implementation of the environment (the trainer collects
experience from 64 copies, the evaluator runs 1000 test episodes together);
``multi_agent_env`` describes observations and actions and holds the course interface.
"""

from __future__ import annotations

import numpy as np

# ------------------------------------------------------------------ the maps
# A map is an int64 array (H, W): 0 free, 1 obstacle, 2 the single target; every free cell
# must be able to reach the target.
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


# ------------------------------------------------------------------ the environment
BOTH_ON_TARGET_REWARD = 10.0
ARRIVAL_REWARD = 2.0
STEP_REWARD = -0.1
REWARD_MODES = ("per_step", "arrival", "goal")  # per_step: the envs' default, not the trainer's

# One agent's observation: its w x w patch (w² elements, row-major), then the partner's last
# message (element w²) and the distance between the agents (w² + 1); for the default w = 3:
OBSERVATION_DIM = 11
MESSAGE_INDEX = 9
DISTANCE_INDEX = 10
MASKED_INPUTS = {  # the observation elements each ablation mode zeroes (3 x 3 window)
    "independent": (MESSAGE_INDEX, DISTANCE_INDEX),  # patch only
    "comm": (DISTANCE_INDEX,),  # patch + message
    "distance": (MESSAGE_INDEX,),  # patch + distance (beyond the assignment's three)
    "full": (),  # patch + message + distance
}


def team_rewards(on_target: np.ndarray, first_arrival: np.ndarray, reward_mode: str) -> np.ndarray:
    """One team reward (N,) per step, from who stands on the target (``on_target`` (N, 2)
    bool) and who reaches it for the first time in the episode (``first_arrival`` (N, 2)).

    ================================  =====================  ==============  ========
    after the joint move              ``per_step``           ``arrival``     ``goal``
    ================================  =====================  ==============  ========
    both agents on the target (ends)  +10                    +10             +10
    exactly one agent on the target   +2 (every such step)   -0.1            -0.1
    an agent first reaches the target +2 / -0.1 as above     +2              -0.1
    otherwise                         -0.1                   -0.1            -0.1
    ================================  =====================  ==============  ========

    ``per_step`` (the assignment's table) is the environments' default, ``goal`` the
    trainer's (which adds its own arrival term, ``--target_potential``).
    """
    both = on_target[:, 0] & on_target[:, 1]
    if reward_mode == "per_step":
        pays_bonus = on_target[:, 0] != on_target[:, 1]  # exactly one on the target
    elif reward_mode == "arrival":
        pays_bonus = first_arrival.any(axis=1)
    else:
        pays_bonus = np.zeros(len(on_target), dtype=bool)
    rewards = np.where(pays_bonus, ARRIVAL_REWARD, STEP_REWARD)
    rewards[both] = BOTH_ON_TARGET_REWARD
    return rewards


class VectorMultiAgentEnv:
    """``n_envs`` copies stepped together; all state lives in NumPy arrays.

    Positions are flat indices into the map padded by ``obs_window // 2`` cells of -1, so a
    move is one addition, a wall check one lookup and a patch one gather. ``seed`` draws the
    map (unless ``grid`` is given) and, through a spawned stream, the agents' start cells.

    The tables are built for a stack of M maps (map m's cells are flat indices ``m * P ..
    m * P + P - 1``, P padded cells per map); the core plays one. A subclass may give the
    copies several (``studies/pool_training.py``): it overrides :meth:`_choose_maps` and
    :meth:`_before_placement`, and sees each step's state before the auto-reset in
    :meth:`_after_move`.

    One team reward per step (:func:`team_rewards`). Both agents on the target terminates
    the episode; ``truncated`` is set when ``max_steps`` steps pass without it.
    """

    def __init__(
        self,
        n_envs: int,
        grid_size: tuple[int, int] = (10, 10),
        obs_window: int = 3,
        max_steps: int = 50,
        seed: int | None = None,
        reward_mode: str = "per_step",
        grid: np.ndarray | None = None,
        auto_reset: bool = True,
    ) -> None:
        self.n_envs = positive_int(n_envs, "n_envs")
        if not is_integer(obs_window) or obs_window < 3 or obs_window % 2 == 0:
            raise ValueError(f"obs_window must be an odd integer >= 3, got {obs_window!r}")
        self.obs_window = int(obs_window)
        self.max_steps = positive_int(max_steps, "max_steps")
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"reward_mode must be one of {REWARD_MODES}, got {reward_mode!r}")
        self.reward_mode = reward_mode
        seed = check_seed(seed)
        self.auto_reset = bool(auto_reset)
        self.grids, self.grid = self._choose_maps(grid_size, seed, grid)
        self.grid_size: tuple[int, int] = (int(self.grids.shape[1]), int(self.grids.shape[2]))
        self.obs_dim = self.obs_window**2 + 2
        self._rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        self._build_lookup_tables()
        self._map_index = np.zeros(self.n_envs, dtype=np.int64)  # (N,) each copy's map
        self._copy_base = self._map_index * self._cells_per_map  # first flat index of the map
        self._copy_target = self._target_flat[self._map_index]  # (N,) flat target cells
        self._flat = np.zeros((self.n_envs, 2), dtype=np.int64)
        self._messages = np.zeros((self.n_envs, 2), dtype=np.float32)
        self._steps = np.zeros(self.n_envs, dtype=np.int64)
        self._visited = np.zeros((self.n_envs, 2), dtype=bool)  # reached the target yet
        self._finished = np.zeros(self.n_envs, dtype=bool)  # only set when not auto_reset
        self.reset()

    def _choose_maps(
        self, grid_size: tuple[int, int], seed: int | None, grid: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The stack of maps (M, H, W) and the one map if M = 1 (:func:`choose_map`)."""
        one_map = choose_map(grid_size, seed, grid)
        return one_map[None], one_map

    def _build_lookup_tables(self) -> None:
        """Tables over the M stacked padded maps (flat index m * P + cell)."""
        rows, cols = self.grid_size
        n_maps = len(self.grids)
        pad = self._pad = self.obs_window // 2
        self._padded_cols = padded_cols = cols + 2 * pad
        padded = np.full((n_maps, rows + 2 * pad, padded_cols), OFF_GRID, dtype=np.float32)
        padded[:, pad : pad + rows, pad : pad + cols] = self.grids
        self._cells_per_map = cells_per_map = padded[0].size
        self._cell_values = padded.ravel()
        self._passable = (self._cell_values == FREE) | (self._cell_values == TARGET)
        self._move_offsets = ACTION_DELTAS @ np.array([padded_cols, 1])
        # Per-cell lookup tables, so an observation is two gathers. Entries of padding
        # cells are never read (agents stay inside the grid).
        all_cells = np.arange(padded.size)
        patch_rows, patch_cols = np.mgrid[-pad : pad + 1, -pad : pad + 1]
        self._patch_offsets = patch_offsets = (patch_rows * padded_cols + patch_cols).ravel()
        self._patches = np.take(self._cell_values, all_cells[:, None] + patch_offsets, mode="clip")
        local_cells = all_cells % cells_per_map
        self._row_col = np.stack(np.divmod(local_cells, padded_cols), axis=-1) - pad  # (MP, 2)
        self._diagonal = np.hypot(rows, cols)  # the distance's normaliser
        free = (self._cell_values == FREE).reshape(n_maps, cells_per_map)
        self._free_counts = free.sum(axis=1)  # (M,)
        # (M, max free) flat free cells of each map, sorted, padded with its first one
        order = np.argsort(~free, axis=1, kind="stable")[:, : self._free_counts.max()]
        self._start_cells_by_map = order + (np.arange(n_maps) * cells_per_map)[:, None]
        self._target_flat = np.flatnonzero(self._cell_values == TARGET)  # (M,)

    def _to_flat(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Flat cell indices within one padded map (add ``_copy_base`` for copy i's map)."""
        return (np.asarray(rows) + self._pad) * self._padded_cols + np.asarray(cols) + self._pad

    def _bases_for(self, rows: np.ndarray) -> np.ndarray | int:
        """Offsets of each copy's map, broadcastable to ``rows`` (leading axis: copies)."""
        if len(self.grids) == 1:
            return 0
        if rows.ndim == 0 or rows.shape[0] != self.n_envs:
            raise ValueError(f"several maps: cells need a leading axis of {self.n_envs} copies")
        return self._copy_base.reshape((-1,) + (1,) * (rows.ndim - 1))

    def _check_cells(self, positions: object, name: str) -> np.ndarray:
        """Flat cells of ``positions`` (N, 2, 2) (row, col); ValueError naming ``name``
        unless they are integer cells inside the grid, not obstacles."""
        positions = np.asarray(positions)
        if positions.shape != (self.n_envs, 2, 2) or positions.dtype.kind not in "iu":
            raise ValueError(
                f"{name} must be integers of shape ({self.n_envs}, 2, 2), "
                f"got {positions.dtype} {positions.shape}"
            )
        if not self.is_passable(positions[..., 0], positions[..., 1]).all():
            raise ValueError(
                f"{name} must be cells inside the {self.grid_size[0]}x{self.grid_size[1]} grid "
                f"and not obstacles, got {positions.tolist()}"
            )
        rows, cols = positions[..., 0], positions[..., 1]
        return self._to_flat(rows, cols) + self._bases_for(rows)

    # ----------------------------------------------------------------------------- state
    @property
    def positions(self) -> np.ndarray:
        """Current agent positions (N, 2, 2) int64 as (row, col)."""
        return self._rows_cols(self._flat)

    def _rows_cols(self, flat: np.ndarray) -> np.ndarray:
        return np.take(self._row_col, flat, axis=0)  # np.take: faster than fancy indexing

    @property
    def steps(self) -> np.ndarray:
        """Steps taken in the current episode of each copy, (N,) int64."""
        return self._steps.copy()

    def _single_map(self, name: str) -> None:
        if self.grid is None:
            raise ValueError(f"{name} needs one map; this environment holds several (grids)")

    @property
    def target_position(self) -> tuple[int, int]:
        """The target cell of the one map (ValueError with several maps)."""
        self._single_map("target_position")
        row, col = self._row_col[self._target_flat[0]]
        return int(row), int(col)

    def is_passable(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Bool array: inside the grid and not an obstacle (with several maps, the leading
        axis is the copy)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        inside = (rows >= 0) & (rows < self.grid_size[0]) & (cols >= 0) & (cols < self.grid_size[1])
        flat = self._to_flat(np.where(inside, rows, 0), np.where(inside, cols, 0))
        return inside & self._passable[flat + self._bases_for(rows)]

    # ------------------------------------------------------------------------ dynamics
    def _move(self, flat: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """New flat positions, same shape as ``flat``; blocked moves stay in place."""
        proposed = flat + np.take(self._move_offsets, actions)
        return np.where(np.take(self._passable, proposed), proposed, flat)

    def _observe(self, flat: np.ndarray, messages: np.ndarray) -> np.ndarray:
        """Observations (n, 2, w² + 2) float32 from flat positions and sent messages (n, 2):
        the patch, the partner's message, the distance."""
        patch_size = self.obs_window**2
        obs = np.empty((flat.shape[0], 2, patch_size + 2), dtype=np.float32)
        obs[:, :, :patch_size] = np.take(self._patches, flat, axis=0)
        obs[:, :, patch_size] = messages[:, ::-1]  # each agent receives its partner's
        offset = self._row_col[flat[:, 0]] - self._row_col[flat[:, 1]]
        distance = np.hypot(offset[:, 0], offset[:, 1]) / self._diagonal
        obs[:, :, patch_size + 1] = distance[:, None]
        return obs

    def current_observations(self) -> np.ndarray:
        """Observations (N, 2, obs_dim) float32 of the current state."""
        return self._observe(self._flat, self._messages)

    def _before_placement(self, rows: np.ndarray) -> None:
        """Hook: copies ``rows`` start new episodes (a subclass may change their maps)."""

    def _after_move(self, info: dict[str, np.ndarray]) -> None:
        """Hook: after each move, before finished copies restart (a subclass may add to
        ``info``)."""

    def _start_episodes(self, rows: np.ndarray, flat: np.ndarray | None = None) -> None:
        """Begin new episodes in copies ``rows``: agents on distinct random free cells (or
        ``flat``), messages, counters and arrival flags cleared."""
        if flat is None:
            maps = self._map_index[rows]
            n_cells = self._free_counts[maps][:, None] - np.array([0, 1])  # A's, then B's
            # floor(uniform * n): uniform on 0..n-1, several times faster than Generator.integers
            cells = (self._rng.random((len(rows), 2)) * n_cells).astype(np.int64)
            cells[:, 1] += cells[:, 1] >= cells[:, 0]  # B uniform over the cells A left
            flat = self._start_cells_by_map[maps[:, None], cells]
        self._flat[rows] = flat
        self._messages[rows] = 0.0
        self._steps[rows] = 0
        self._visited[rows] = flat == self._copy_target[rows, None]
        self._finished[rows] = False

    def reset(self, seed: int | None = None, positions: np.ndarray | None = None) -> np.ndarray:
        """Start a new episode in every copy; return observations (N, 2, obs_dim) float32.
        ``seed`` reseeds the start cells (fixed evaluation episodes); ``positions`` (N, 2, 2)
        places the agents by hand (passable cells, not both on the target)."""
        if check_seed(seed) is not None:
            self._rng = np.random.default_rng(seed)
        every_copy = np.arange(self.n_envs)
        self._before_placement(every_copy)
        flat = None
        if positions is not None:
            flat = self._check_cells(positions, "positions")
            if (flat == self._copy_target[:, None]).all(axis=1).any():
                raise ValueError("both agents start on the target: the episode would be over")
        self._start_episodes(every_copy, flat)
        return self.current_observations()

    def step(
        self, actions: np.ndarray, messages: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every copy one step.

        Args: ``actions`` (N, 2) ints in 0..4; ``messages`` (N, 2) the messages sent now,
        clipped into [0, 1] (the partner reads them in the returned observation). Returns
        ``(obs (N, 2, obs_dim), rewards (N,), terminated (N,), truncated (N,), info)``. With
        ``auto_reset`` finished copies restart and ``obs`` is the new episode's; ``info``
        holds the state before: ``final_obs``, ``positions`` (N, 2, 2), ``on_target`` (N, 2)
        and ``steps`` (N,). Without it, stepping a finished copy raises ValueError.
        """
        actions, messages = check_step(actions, messages, self.n_envs)
        if self._finished.any():
            raise ValueError(
                f"episode over in copies {np.flatnonzero(self._finished)}; "
                "call reset() before step()"
            )
        flat = self._flat = self._move(self._flat, actions)
        self._messages = messages
        self._steps += 1
        on_target = flat == self._copy_target[:, None]
        rewards = team_rewards(on_target, on_target & ~self._visited, self.reward_mode)
        self._visited |= on_target
        terminated = on_target[:, 0] & on_target[:, 1]
        truncated = (self._steps >= self.max_steps) & ~terminated
        obs = self._observe(flat, messages)
        info = {
            "final_obs": obs.copy(),
            "positions": self._rows_cols(flat),
            "on_target": on_target,
            "steps": self._steps.copy(),
        }
        self._after_move(info)
        finished = terminated | truncated
        if not self.auto_reset:
            self._finished = finished
        elif finished.any():
            rows = np.flatnonzero(finished)
            self._before_placement(rows)
            self._start_episodes(rows)
            obs[rows] = self._observe(self._flat[rows], self._messages[rows])
        return obs, rewards, terminated, truncated, info
