"""Two-agent cooperative grid world with partial observation and a learned message channel.

Both agents must stand on the single target cell on the same step. Each agent sees an
``obs_window × obs_window`` patch around itself, the message its partner sent on the
previous step and the normalised distance between the two agents.

``MultiAgentEnv`` is the course interface, a thin N = 1 view of
``vector_env.VectorMultiAgentEnv`` (the dynamics, observations and rewards); maps are made
in ``vector_env.py``.

Observation of one agent (length ``obs_window² + 2``, 11 for the default window of 3):
  0..8  the patch, row-major (0 free, 1 obstacle, 2 target, -1 off-grid; agents not drawn)
  9     the partner's last message (0.0 at reset)
  10    Euclidean distance between the agents / sqrt(H² + W²)
Actions: 0 Up (row - 1), 1 Down (row + 1), 2 Left (col - 1), 3 Right (col + 1), 4 Stay.
A move into a wall or an obstacle leaves the agent in place; agents may share a cell.
Positions are (row, col), row 0 at the top.
"""

from __future__ import annotations

import numpy as np
from vector_env import FREE, NUM_ACTIONS, OBSTACLE, TARGET, VectorMultiAgentEnv


def _single_number(value: object, name: str) -> int | float:
    """A Python int or float from a number or a one-element array; ValueError naming
    ``name`` otherwise (booleans and strings are not numbers here)."""
    array = np.asarray(value)
    if array.size != 1 or array.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a single number, got {value!r}")
    return array.reshape(()).item()


def _action(value: object, name: str) -> int:
    allowed = f"{name} must be an integer in 0..{NUM_ACTIONS - 1}"
    if np.asarray(value).dtype.kind == "b":
        raise ValueError(f"{allowed}, got the boolean {value!r}")
    number = _single_number(value, name)
    if not isinstance(number, int) or not 0 <= number < NUM_ACTIONS:
        raise ValueError(f"{allowed}, got {value!r}")
    return number


def _message(value: object, name: str) -> float:
    number = float(_single_number(value, name))
    if not np.isfinite(number):
        raise ValueError(f"{name} must be a finite number (clipped into [0, 1]), got {value!r}")
    return number


def render_state(
    grid: np.ndarray, positions: np.ndarray, step: int, max_steps: int, messages
) -> str:
    """Text picture of one state: A, B (* when sharing a cell), T target, X obstacle, and
    the step with the messages just sent."""
    cells = np.array([".", "X", "T"])[np.where(grid == OBSTACLE, 1, np.where(grid == TARGET, 2, 0))]
    (row_a, col_a), (row_b, col_b) = positions
    cells[row_a, col_a] = "A"
    cells[row_b, col_b] = "*" if (row_a, col_a) == (row_b, col_b) else "B"
    picture = "\n".join(" ".join(row) for row in cells)
    return (
        f"{picture}\nstep {step}/{max_steps}  message A->B {float(messages[0]):.2f}  "
        f"B->A {float(messages[1]):.2f}"
    )


class _OneCopy(VectorMultiAgentEnv):
    """The vector environment with what the course interface reads and sets besides a step:
    the agents moved by hand, the messages, one move from a cell."""

    @VectorMultiAgentEnv.positions.setter
    def positions(self, positions: np.ndarray) -> None:
        """Move the agents by hand to (N, 2, 2) passable cells; the episode goes on (step
        count and messages kept), an agent placed on the target having reached it."""
        self._flat = self._check_cells(positions, "positions")
        self._visited |= self._flat == self._copy_target[:, None]

    @property
    def messages(self) -> np.ndarray:
        """Last messages sent (N, 2) float32: [:, 0] by A, [:, 1] by B."""
        return self._messages.copy()

    def next_cell(self, row: int, col: int, action: int) -> np.ndarray:
        """The cell (2,) reached from the passable cell (row, col) by ``action``."""
        return self._rows_cols(self._move(self._to_flat(row, col), action))


class MultiAgentEnv:
    """One environment with the course interface: an N = 1 view of VectorMultiAgentEnv.

    Starter attributes, always in sync with the state: ``agent_positions`` (settable),
    ``comm_signals`` ([message from A, message from B]), ``step_count``, ``target_pos``.
    ``step`` after the episode ended raises ValueError."""

    def __init__(
        self,
        grid_size: tuple[int, int] = (10, 10),
        obs_window: int = 3,
        max_steps: int = 50,
        seed: int | None = None,
        reward_mode: str = "per_step",
        grid: np.ndarray | None = None,
    ) -> None:
        self._vector = _OneCopy(
            1, grid_size, obs_window, max_steps, seed, reward_mode, grid, auto_reset=False
        )
        self.grid_size = self._vector.grid_size
        self.obs_window = self._vector.obs_window
        self.max_steps = self._vector.max_steps
        self.reward_mode = reward_mode
        self.grid = self._vector.grid

    @property
    def agent_positions(self) -> list[tuple[int, int]]:
        """[(row_A, col_A), (row_B, col_B)]; assign two cells to move the agents there."""
        return [(int(r), int(c)) for r, c in self._vector.positions[0]]

    @agent_positions.setter
    def agent_positions(self, positions: list[tuple[int, int]]) -> None:
        self._vector.positions = np.asarray(positions)[None]

    @property
    def comm_signals(self) -> list[float]:
        """[last message sent by A, last message sent by B] (0.0 after a reset)."""
        return [float(m) for m in self._vector.messages[0]]

    @property
    def step_count(self) -> int:
        """Steps taken in the current episode."""
        return int(self._vector.steps[0])

    @property
    def target_pos(self) -> tuple[int, int]:
        return self._vector.target_position

    def reset(
        self, seed: int | None = None, positions: list | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Place both agents anew; return (obs_A, obs_B), each (obs_dim,) float32.
        ``seed`` and ``positions`` ((row, col) of A and of B) as in the vector env."""
        obs = self._vector.reset(seed, None if positions is None else np.asarray(positions)[None])
        return obs[0, 0], obs[0, 1]

    def step(
        self, action_A: int, action_B: int, comm_A: float, comm_B: float
    ) -> tuple[tuple[np.ndarray, np.ndarray], float, bool]:
        """One joint step: ((obs_A, obs_B), team reward, done). ``done`` is True when both
        agents stand on the target or ``max_steps`` steps have passed. Messages are clipped
        into [0, 1]. The team reward (``vector_env.team_rewards``, one value per step): +10
        when both stand on the target; with this environment's default ``reward_mode``
        ``per_step`` (the assignment's table; the trainer learns from ``goal``) +2 on every
        step on which exactly one does; -0.1 otherwise."""
        actions = np.array([[_action(action_A, "action_A"), _action(action_B, "action_B")]])
        messages = np.array([[_message(comm_A, "comm_A"), _message(comm_B, "comm_B")]])
        obs, rewards, terminated, truncated, _ = self._vector.step(actions, messages)
        return (obs[0, 0], obs[0, 1]), float(rewards[0]), bool(terminated[0] or truncated[0])

    def _get_observation(self, agent_idx: int) -> np.ndarray:
        """Current observation (obs_dim,) float32 of agent 0 (A) or 1 (B)."""
        if agent_idx not in (0, 1):
            raise ValueError(f"agent_idx must be 0 (A) or 1 (B), got {agent_idx!r}")
        return self._vector.current_observations()[0, agent_idx]

    def _is_valid_position(self, pos: tuple[int, int]) -> bool:
        """True if ``pos`` is inside the grid and not an obstacle."""
        return bool(self._vector.is_passable(pos[0], pos[1]))

    def _apply_action(self, pos: tuple[int, int], action: int) -> tuple[int, int]:
        """Cell reached from ``pos`` by ``action`` (``pos`` itself if the move is blocked)."""
        if not self._is_valid_position(pos):
            raise ValueError(f"pos {pos} is off the grid or on an obstacle")
        row, col = self._vector.next_cell(pos[0], pos[1], _action(action, "action"))
        return int(row), int(col)

    def _find_free_cells(self) -> list[tuple[int, int]]:
        """Free cells (value 0, not the target) as (row, col): where agents may start."""
        return [(int(r), int(c)) for r, c in np.argwhere(self.grid == FREE)]

    def render(self) -> None:
        """Print the grid with the agents, the step and the last messages."""
        positions, messages = self._vector.positions[0], self._vector.messages[0]
        print(render_state(self.grid, positions, self.step_count, self.max_steps, messages))
