"""The dynamics, observations and rewards of Problem 2, for N copies of one map at once.

``VectorMultiAgentEnv`` holds the only implementation of the environment, stepping N copies
with NumPy arrays (the trainer collects experience from 64 copies, the evaluator runs 1000
test episodes together). ``multi_agent_env.MultiAgentEnv`` is the course interface: a thin
N = 1 view of it. Observations, actions and rewards are described in ``multi_agent_env``.
"""

from __future__ import annotations

import numpy as np
from grid_maps import (
    ACTION_DELTAS,
    FREE,
    NUM_ACTIONS,
    OFF_GRID,
    TARGET,
    check_grid,
    generate_map,
)

BOTH_ON_TARGET_REWARD = 10.0
ARRIVAL_REWARD = 2.0
STEP_REWARD = -0.1
REWARD_MODES = ("per_step", "arrival")  # the first is the default: the assignment's table
MAX_TABULATED_CELLS = 4096  # padded cells; the (P, P) float32 table is then ≤ 64 MiB


def _is_integer(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _positive_int(value: object, name: str) -> int:
    if not _is_integer(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _check_seed(seed: object, name: str = "seed") -> int | None:
    """``None`` or a non-negative integer (what NumPy's generators accept)."""
    if seed is not None and (not _is_integer(seed) or seed < 0):
        raise ValueError(f"{name} must be None or a non-negative integer, got {seed!r}")
    return None if seed is None else int(seed)


class VectorMultiAgentEnv:
    """``n_envs`` copies of one map stepped together; all state lives in NumPy arrays.

    Positions are kept as flat indices into the map padded by ``obs_window // 2`` cells of
    -1 on each side, so a move is one addition, a wall check one lookup and an observation
    patch one gather. ``seed`` draws the map (unless ``grid`` is given, which is validated
    and used instead, its shape replacing ``grid_size``) and, through a separate stream
    spawned with ``np.random.SeedSequence``, the agents' start cells.

    One team reward per step (never a per-agent sum):
      * ``reward_mode="per_step"`` (default, the assignment's table): +10 when both agents
        stand on the target (the episode terminates), +2 on every step on which exactly one
        agent stands on it, -0.1 otherwise.
      * ``reward_mode="arrival"`` (the shaped reward the trainer learns from): +10 when both
        stand on the target (terminates), +2 on a step on which an agent reaches the target
        for the first time in the episode, -0.1 otherwise. Leaving and coming back pays
        nothing; an agent placed on the target at the start has already "arrived".
    ``truncated`` is set when ``max_steps`` steps pass without termination.
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
        self.n_envs = _positive_int(n_envs, "n_envs")
        if not _is_integer(obs_window) or obs_window < 3 or obs_window % 2 == 0:
            raise ValueError(f"obs_window must be an odd integer >= 3, got {obs_window!r}")
        self.obs_window = int(obs_window)
        self.max_steps = _positive_int(max_steps, "max_steps")
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"reward_mode must be one of {REWARD_MODES}, got {reward_mode!r}")
        self.reward_mode = reward_mode
        seed = _check_seed(seed)
        self.auto_reset = bool(auto_reset)
        self.grid = generate_map(grid_size, seed) if grid is None else check_grid(grid)
        self.grid.flags.writeable = False
        self.grid_size: tuple[int, int] = (int(self.grid.shape[0]), int(self.grid.shape[1]))
        self.obs_dim = self.obs_window**2 + 2
        self._rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        self._build_lookup_tables()
        self._flat = np.zeros((self.n_envs, 2), dtype=np.int64)
        self._messages = np.zeros((self.n_envs, 2), dtype=np.float32)
        self._steps = np.zeros(self.n_envs, dtype=np.int64)
        self._visited = np.zeros((self.n_envs, 2), dtype=bool)  # reached the target yet
        self._finished = np.zeros(self.n_envs, dtype=bool)  # only set when not auto_reset
        self.reset()

    def _build_lookup_tables(self) -> None:
        rows, cols = self.grid_size
        pad = self._pad = self.obs_window // 2
        self._padded_cols = padded_cols = cols + 2 * pad
        padded = np.full((rows + 2 * pad, padded_cols), OFF_GRID, dtype=np.float32)
        padded[pad : pad + rows, pad : pad + cols] = self.grid
        self._cell_values = padded.ravel()
        self._passable = (self._cell_values == FREE) | (self._cell_values == TARGET)
        self._move_offsets = ACTION_DELTAS @ np.array([padded_cols, 1])
        # Per-cell lookup tables, so an observation is two gathers. Entries of padding
        # cells are never read (agents stay inside the grid).
        all_cells = np.arange(padded.size)
        patch_rows, patch_cols = np.mgrid[-pad : pad + 1, -pad : pad + 1]
        patch_offsets = (patch_rows * padded_cols + patch_cols).ravel()
        self._patches = np.take(self._cell_values, all_cells[:, None] + patch_offsets, mode="clip")
        self._row_col = np.stack(np.divmod(all_cells, padded_cols), axis=-1) - pad  # (P, 2)
        self._distances = None  # (P, P) normalised distances, if small enough to tabulate
        if padded.size <= MAX_TABULATED_CELLS:
            offsets = self._row_col[:, None, :] - self._row_col[None, :, :]
            self._distances = (
                np.hypot(offsets[..., 0], offsets[..., 1]) / np.hypot(rows, cols)
            ).astype(np.float32)
        self._start_cells = np.flatnonzero(self._cell_values == FREE)
        self._target_flat = int(np.flatnonzero(self._cell_values == TARGET)[0])

    def _to_flat(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return (np.asarray(rows) + self._pad) * self._padded_cols + np.asarray(cols) + self._pad

    def _check_cells(self, positions: object, name: str) -> np.ndarray:
        """``positions`` (N, 2, 2) integer (row, col) cells inside the grid, not obstacles."""
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
        return self._to_flat(positions[..., 0], positions[..., 1])

    # ----------------------------------------------------------------------------- state
    @property
    def positions(self) -> np.ndarray:
        """Current agent positions (N, 2, 2) int64 as (row, col)."""
        return self._rows_cols(self._flat)

    def _rows_cols(self, flat: np.ndarray) -> np.ndarray:
        return np.take(self._row_col, flat, axis=0)  # np.take: faster than fancy indexing

    @positions.setter
    def positions(self, positions: np.ndarray) -> None:
        """Move the agents by hand to (N, 2, 2) cells (inside the grid, not obstacles); the
        episode goes on from there (step count and messages kept). An agent placed on the
        target counts as having reached it (no arrival bonus for that)."""
        self._flat = self._check_cells(positions, "positions")
        self._visited |= self._flat == self._target_flat

    @property
    def messages(self) -> np.ndarray:
        """Last messages sent (N, 2) float32: [:, 0] by A, [:, 1] by B."""
        return self._messages.copy()

    @property
    def steps(self) -> np.ndarray:
        """Steps taken in the current episode of each copy, (N,) int64."""
        return self._steps.copy()

    @property
    def target_position(self) -> tuple[int, int]:
        row, col = self._row_col[self._target_flat]
        return int(row), int(col)

    @property
    def free_cells(self) -> np.ndarray:
        """Cells (M, 2) of value 0 (free, not the target): where ``reset`` places agents."""
        return self._rows_cols(self._start_cells)

    def is_passable(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Bool array: inside the grid and not an obstacle (free or target)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        inside = (rows >= 0) & (rows < self.grid_size[0]) & (cols >= 0) & (cols < self.grid_size[1])
        flat = self._to_flat(np.where(inside, rows, 0), np.where(inside, cols, 0))
        return inside & self._passable[flat]

    # ------------------------------------------------------------------------ dynamics
    def _move(self, flat: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """New flat positions, same shape as ``flat``; blocked moves stay in place."""
        proposed = flat + np.take(self._move_offsets, actions)
        return np.where(np.take(self._passable, proposed), proposed, flat)

    def next_cells(self, rows: np.ndarray, cols: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Cells (..., 2) reached from passable cells ``(rows, cols)`` by ``actions`` (same
        shape, ints 0..4); a move into a wall or an obstacle stays in place."""
        actions = np.asarray(actions)
        if actions.dtype.kind not in "iu" or (actions < 0).any() or (actions >= NUM_ACTIONS).any():
            raise ValueError(f"actions must be integers in 0..{NUM_ACTIONS - 1}, got {actions}")
        if not self.is_passable(rows, cols).all():
            raise ValueError("cells must be inside the grid and not obstacles")
        return self._rows_cols(self._move(self._to_flat(rows, cols), actions))

    def _observe(self, flat: np.ndarray, messages: np.ndarray) -> np.ndarray:
        """Observations (n, 2, obs_dim) float32 from flat positions and sent messages (n, 2)."""
        patch_size = self.obs_window**2
        obs = np.empty((flat.shape[0], 2, self.obs_dim), dtype=np.float32)
        obs[:, :, :patch_size] = np.take(self._patches, flat, axis=0)
        obs[:, :, patch_size] = messages[:, ::-1]  # each agent receives its partner's
        if self._distances is not None:
            distance = self._distances[flat[:, 0], flat[:, 1]]
        else:
            offset = self._row_col[flat[:, 0]] - self._row_col[flat[:, 1]]
            distance = np.hypot(offset[:, 0], offset[:, 1]) / np.hypot(*self.grid_size)
        obs[:, :, patch_size + 1] = distance[:, None]
        return obs

    def current_observations(self) -> np.ndarray:
        """Observations (N, 2, obs_dim) float32 of the current state."""
        return self._observe(self._flat, self._messages)

    def _start_episodes(self, rows: np.ndarray, flat: np.ndarray | None = None) -> None:
        """Begin new episodes in copies ``rows``: place agents (random distinct free
        cells unless ``flat`` is given), clear messages, counters and arrival flags."""
        if flat is None:
            n_cells = len(self._start_cells)
            # floor(uniform * n) is uniform on 0..n-1 and several times faster than
            # Generator.integers for small batches.
            cells = (self._rng.random((len(rows), 2)) * (n_cells, n_cells - 1)).astype(np.int64)
            cells[:, 1] += cells[:, 1] >= cells[:, 0]  # B uniform over the cells A left
            flat = self._start_cells[cells]
        self._flat[rows] = flat
        self._messages[rows] = 0.0
        self._steps[rows] = 0
        self._visited[rows] = flat == self._target_flat
        self._finished[rows] = False

    def reset(self, seed: int | None = None, positions: np.ndarray | None = None) -> np.ndarray:
        """Start a new episode in every copy; return observations (N, 2, obs_dim) float32.

        ``seed`` reseeds the placement RNG (fixed evaluation episodes). ``positions``
        (N, 2, 2) places the agents by hand instead: any non-obstacle cells inside the
        grid, the target included, but not both on the target. An agent starting on the
        target earns no arrival bonus for it.
        """
        if _check_seed(seed) is not None:
            self._rng = np.random.default_rng(seed)
        flat = None
        if positions is not None:
            flat = self._check_cells(positions, "positions")
            if (flat == self._target_flat).all(axis=1).any():
                raise ValueError("both agents start on the target: the episode would be over")
        self._start_episodes(np.arange(self.n_envs), flat)
        return self.current_observations()

    def check_actions(self, actions: np.ndarray) -> np.ndarray:
        """``actions`` as an (N, 2) integer array in 0..4, or ValueError."""
        actions = np.asarray(actions)
        if actions.shape != (self.n_envs, 2):
            raise ValueError(f"actions must have shape ({self.n_envs}, 2), got {actions.shape}")
        if actions.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers 0..4, got dtype {actions.dtype}")
        if actions.min() < 0 or actions.max() >= NUM_ACTIONS:
            bad = np.unique(actions[(actions < 0) | (actions >= NUM_ACTIONS)])
            raise ValueError(f"actions must be in 0..4 (Up, Down, Left, Right, Stay), got {bad}")
        return actions

    def _check_messages(self, messages: np.ndarray) -> np.ndarray:
        """Finite numbers, clipped into [0, 1] (the channel is bounded); NaN, inf or a
        non-number raises ValueError."""
        messages = np.asarray(messages)
        if messages.shape != (self.n_envs, 2) or messages.dtype.kind not in "fiub":
            raise ValueError(
                f"messages must be numbers of shape ({self.n_envs}, 2), "
                f"got {messages.dtype} {messages.shape}"
            )
        if not np.isfinite(messages).all():
            raise ValueError(
                f"messages must be finite numbers (clipped into [0, 1]), got {messages}"
            )
        return np.clip(messages, 0.0, 1.0).astype(np.float32)

    def step(
        self, actions: np.ndarray, messages: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every copy one step.

        Args: ``actions`` (N, 2) ints in 0..4; ``messages`` (N, 2) finite numbers, clipped
        into [0, 1], the message each agent sends now (its partner reads it in the returned
        observation). Returns ``(obs (N, 2, obs_dim) float32, rewards (N,) float64,
        terminated (N,) bool, truncated (N,) bool, info)``. With ``auto_reset`` the copies
        that finished start a new episode and ``obs`` holds its first observation; ``info``
        describes the state before that reset: ``final_obs`` (N, 2, obs_dim), ``positions``
        (N, 2, 2), ``on_target`` (N, 2) bool, ``steps`` (N,) steps taken in the episode.
        Without ``auto_reset``, stepping after a copy finished raises ValueError.
        """
        actions = self.check_actions(actions)
        messages = self._check_messages(messages)
        if self._finished.any():
            raise ValueError(
                f"episode over in copies {np.flatnonzero(self._finished)}; "
                "call reset() before step()"
            )
        flat = self._flat = self._move(self._flat, actions)
        self._messages = messages
        self._steps += 1
        on_target = flat == self._target_flat
        both_on_target = on_target[:, 0] & on_target[:, 1]
        if self.reward_mode == "per_step":
            pays_bonus = on_target[:, 0] != on_target[:, 1]  # exactly one on the target
        else:
            pays_bonus = (on_target & ~self._visited).any(axis=1)  # a first arrival
        rewards = np.where(pays_bonus, ARRIVAL_REWARD, STEP_REWARD)
        rewards[both_on_target] = BOTH_ON_TARGET_REWARD
        self._visited |= on_target
        terminated = both_on_target
        truncated = (self._steps >= self.max_steps) & ~terminated
        obs = self._observe(flat, messages)
        info = {
            "final_obs": obs.copy(),
            "positions": self._rows_cols(flat),
            "on_target": on_target,
            "steps": self._steps.copy(),
        }
        finished = terminated | truncated
        if not self.auto_reset:
            self._finished = finished
        elif finished.any():
            rows = np.flatnonzero(finished)
            self._start_episodes(rows)
            obs[rows] = self._observe(self._flat[rows], self._messages[rows])
        return obs, rewards, terminated, truncated, info

    def render(self, env_index: int = 0) -> None:
        """Print copy ``env_index``: A, B (* when sharing a cell), T target, X obstacle."""
        cells = np.array([".", "X", "T"])[self.grid]
        (row_a, col_a), (row_b, col_b) = self.positions[env_index]
        cells[row_a, col_a] = "A"
        cells[row_b, col_b] = "*" if (row_a, col_a) == (row_b, col_b) else "B"
        print("\n".join(" ".join(row) for row in cells))
        message_a, message_b = self._messages[env_index]
        print(
            f"step {self._steps[env_index]}/{self.max_steps}  message A->B {message_a:.2f}  "
            f"B->A {message_b:.2f}"
        )
