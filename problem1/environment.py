"""A stochastic gridworld for dynamic programming (Problem 1).

The agent moves on a square grid. An action succeeds with probability
``prob_intended`` (0.8); otherwise the agent drifts to one of the two
perpendicular directions with probability ``prob_drift`` (0.1) each. A move
into the outer wall or an obstacle leaves the agent where it is. The reward
depends only on the cell entered: +10 for the goal (the episode ends), -5 for a
penalty cell (the episode goes on), -0.1 for any other cell. Episodes are cut
after ``max_steps`` steps.

Positions are ``(row, col)`` with row 0 at the top; state indices are
``row * grid_size + col``. Actions are clockwise: 0 UP, 1 RIGHT, 2 DOWN, 3 LEFT,
so the drift directions of ``a`` are ``(a - 1) % 4`` and ``(a + 1) % 4``.

Other maps are given as rows of characters (see :data:`LAYOUT_SYMBOLS`)::

    GridWorldEnv(layout=["S..", ".#.", "P.G"])
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np

Position = tuple[int, int]

UP, RIGHT, DOWN, LEFT = 0, 1, 2, 3
ACTION_NAMES = ("UP", "RIGHT", "DOWN", "LEFT")
ACTION_ARROWS = ("↑", "→", "↓", "←")
MOVES: tuple[Position, ...] = ((-1, 0), (0, 1), (1, 0), (0, -1))
OUTCOME_NAMES = ("intended", "drift_left", "drift_right")
# OUTCOME_DIRECTIONS[a] = directions of the three outcomes of action a (intended, left, right).
OUTCOME_DIRECTIONS = np.array([[a, (a - 1) % 4, (a + 1) % 4] for a in range(4)])

LAYOUT_SYMBOLS = {"S": "start", "G": "goal", "#": "obstacle", "P": "penalty", ".": "free"}

# The course map, listed in the course's own order (the graders compare these lists).
COURSE_MAP: dict[str, Any] = {
    "size": 5,
    "start": [(0, 0)],
    "goal": [(4, 4)],
    "obstacle": [(1, 2), (2, 1)],
    "penalty": [(3, 3), (3, 0)],
}


def layout_from_cells(cells: dict[str, Any]) -> tuple[str, ...]:
    """Rows of characters for a map given as lists of cells per kind (see ``COURSE_MAP``)."""
    symbol_of = {name: symbol for symbol, name in LAYOUT_SYMBOLS.items()}
    rows = [["."] * cells["size"] for _ in range(cells["size"])]
    for name in ("start", "goal", "obstacle", "penalty"):
        for r, c in cells[name]:
            rows[r][c] = symbol_of[name]
    return tuple("".join(row) for row in rows)


COURSE_LAYOUT = layout_from_cells(COURSE_MAP)  # ("S....", "..#..", ".#...", "P..P.", "....G")


def _parse_layout(layout: Sequence[str]) -> dict[str, Any]:
    """Validate a character layout and return its size and special cells."""
    if isinstance(layout, str | bytes) or not isinstance(layout, Sequence | np.ndarray):
        raise ValueError(
            "layout must be a list of row strings such as ['S..', '.#.', '..G'], "
            f"got a {type(layout).__name__}: {layout!r:.60}"
        )
    rows = list(layout)
    if not rows:
        raise ValueError("layout is empty: give at least one row of characters")
    size = len(rows)
    cells: dict[str, list[Position]] = {name: [] for name in LAYOUT_SYMBOLS.values()}
    for r, row in enumerate(rows):
        if not isinstance(row, str):
            raise ValueError(f"layout row {r} is {type(row).__name__}, expected a string")
        if len(row) != size:
            raise ValueError(
                f"layout must be square: row {r} has {len(row)} cells, expected {size}"
            )
        for c, symbol in enumerate(row):
            if symbol not in LAYOUT_SYMBOLS:
                raise ValueError(
                    f"layout row {r}, column {c}: unknown symbol {symbol!r}; "
                    f"use one of {''.join(LAYOUT_SYMBOLS)}"
                )
            cells[LAYOUT_SYMBOLS[symbol]].append((r, c))
    for name in ("start", "goal"):
        if len(cells[name]) != 1:
            raise ValueError(f"layout needs exactly one {name} cell, found {len(cells[name])}")
    return {"size": size, **cells}


def check_positive_integer(value: Any, name: str) -> int:
    """``value`` as an int >= 1 (not a bool), else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value}")
    return int(value)


class GridWorldEnv:
    """The 5x5 stochastic gridworld of the assignment (or any square layout).

    Args:
        seed: seed of the environment's own ``np.random.Generator`` (used by ``step``).
        layout: rows of characters ``S`` start, ``G`` goal, ``#`` obstacle,
            ``P`` penalty, ``.`` free; defaults to the course layout. The goal must be
            reachable from the start.
        prob_drift: probability of slipping to each perpendicular side, in [0, 0.5];
            the intended move succeeds with ``1 - 2 * prob_drift``.
        max_steps: episode length limit, an integer >= 1.
    """

    action_names = list(ACTION_NAMES)

    def __init__(
        self,
        seed: int | None = None,
        layout: Sequence[str] | None = None,
        prob_drift: float = 0.1,
        max_steps: int = 50,
    ) -> None:
        if isinstance(prob_drift, bool) or not isinstance(prob_drift, numbers.Real):
            raise ValueError(f"prob_drift must be a number in [0, 0.5], got {prob_drift!r}")
        if not 0.0 <= prob_drift <= 0.5:
            raise ValueError(f"prob_drift must lie in [0, 0.5], got {prob_drift}")
        self.max_steps = check_positive_integer(max_steps, "max_steps")
        parsed = COURSE_MAP if layout is None else _parse_layout(layout)
        self.layout = layout_from_cells(parsed)
        self.grid_size: int = parsed["size"]
        self.n_states: int = self.grid_size**2
        self.action_space = 4
        self.action_names = list(ACTION_NAMES)
        self.start_pos: Position = parsed["start"][0]
        self.goal_pos: Position = parsed["goal"][0]
        self.obstacles: list[Position] = list(parsed["obstacle"])
        self.penalties: list[Position] = list(parsed["penalty"])
        self.goal_reward = 10.0
        self.penalty_reward = -5.0
        self.step_cost = -0.1
        self.prob_drift = float(prob_drift)
        self.prob_intended = 1.0 - 2.0 * self.prob_drift
        self.outcome_probs = np.array([self.prob_intended, self.prob_drift, self.prob_drift])
        # obstacle_mask[r, c]: True on obstacle cells, shape (grid_size, grid_size)
        self.obstacle_mask = np.zeros((self.grid_size, self.grid_size), dtype=bool)
        self.obstacle_mask[tuple(np.array(self.obstacles, dtype=int).reshape(-1, 2).T)] = True
        self.move_table = self._build_move_table()
        self.cell_rewards = self._build_cell_rewards()
        self._check_goal_reachable()
        self.rng = np.random.default_rng(seed)
        self.reset()

    # ------------------------------------------------------------------ episode
    def reset(self) -> int:
        """Put the agent on the start cell and return the start state index."""
        self.current_pos = self.start_pos
        self.steps = 0
        self.done = False
        return self.pos_to_state(self.current_pos)

    def step(self, action: int) -> tuple[int, float, bool, dict[str, Any]]:
        """Sample one transition: ``(next_state, reward, done, info)``.

        ``info`` holds ``position``, ``steps``, ``outcome`` (``"intended"``,
        ``"drift_left"`` or ``"drift_right"``) and ``truncated`` (the step limit,
        not the goal, ended the episode).
        """
        action = self.check_action(action)
        if self.done:
            raise ValueError("step() called after the episode ended; call reset() first")
        outcomes = self.outcomes(self.current_pos, action)
        choice = int(self.rng.choice(len(outcomes), p=[p for _, p in outcomes]))
        self.current_pos = outcomes[choice][0]
        self.steps += 1
        reward = self._calculate_reward(self.current_pos)
        reached_goal = self.current_pos == self.goal_pos
        truncated = not reached_goal and self.steps >= self.max_steps
        self.done = reached_goal or truncated
        info = {
            "position": self.current_pos,
            "steps": self.steps,
            "outcome": OUTCOME_NAMES[choice],
            "truncated": truncated,
        }
        return self.pos_to_state(self.current_pos), reward, self.done, info

    # ------------------------------------------------------------------ model
    def get_transition_prob(self, state: int, action: int) -> dict[int, float]:
        """Next-state index -> probability, duplicates merged (sums to 1)."""
        pos = self.state_to_pos(state)
        return {
            self.pos_to_state(next_pos): p
            for next_pos, p in self._get_next_positions(pos, self.check_action(action))
        }

    def get_reward(self, state: int, action: int, next_state: int) -> float:
        """Reward for entering ``next_state`` (it does not depend on ``state`` or ``action``)."""
        self.check_state(state)
        self.check_action(action)
        return self._calculate_reward(self.state_to_pos(next_state))

    def is_terminal(self, state: int) -> bool:
        """True for the goal state only."""
        return self.state_to_pos(state) == self.goal_pos

    def outcomes(self, pos: Position, action: int) -> list[tuple[Position, float]]:
        """The three outcomes of ``action`` at ``pos``, not merged: ``[(next_pos, prob)]``
        for the intended move, the drift to its left and the drift to its right."""
        action = self.check_action(action)
        next_states = self.move_table[self.pos_to_state(pos), OUTCOME_DIRECTIONS[action]]
        return [
            (self.state_to_pos(int(s)), float(p))
            for s, p in zip(next_states, self.outcome_probs, strict=True)
        ]

    def _get_next_positions(self, pos: Position, action: int) -> list[tuple[Position, float]]:
        """``[(next_pos, prob)]`` with outcomes that land on the same cell merged, in the
        order intended, drift left, drift right; zero-probability outcomes are dropped.

        From ``(0, 0)`` with UP: ``[((0, 0), 0.9), ((0, 1), 0.1)]`` (UP and its left
        drift both bump into the wall).
        """
        merged: dict[Position, float] = {}
        for next_pos, p in self.outcomes(pos, action):
            if p > 0.0:
                merged[next_pos] = merged.get(next_pos, 0.0) + p
        return list(merged.items())

    def _calculate_reward(self, pos: Position) -> float:
        """Reward for entering ``pos``: goal, penalty cell or ordinary step cost."""
        return float(self.cell_rewards[self.pos_to_state(pos)])

    # ------------------------------------------------------------------ geometry
    def _build_move_table(self) -> np.ndarray:
        """``move_table[s, d]``: the state reached from ``s`` by a sure move in direction
        ``d``; ``s`` itself when the outer wall or an obstacle is in the way. Shape (S, 4).

        This table is the only place where the grid dynamics are written down:
        ``step``, ``get_transition_prob`` and the tabular model all read it.
        """
        size = self.grid_size
        rows, cols = np.divmod(np.arange(self.n_states), size)
        table = np.empty((self.n_states, 4), dtype=np.int64)
        for direction, (dr, dc) in enumerate(MOVES):
            r, c = rows + dr, cols + dc
            inside = (r >= 0) & (r < size) & (c >= 0) & (c < size)
            r, c = np.clip(r, 0, size - 1), np.clip(c, 0, size - 1)
            allowed = inside & ~self.obstacle_mask[r, c]
            table[:, direction] = np.where(allowed, r * size + c, rows * size + cols)
        return table

    def _build_cell_rewards(self) -> np.ndarray:
        """Reward for entering each state, shape (S,)."""
        rewards = np.full(self.n_states, self.step_cost)
        for r, c in self.penalties:
            rewards[r * self.grid_size + c] = self.penalty_reward
        rewards[self.pos_to_state(self.goal_pos)] = self.goal_reward
        return rewards

    def _check_goal_reachable(self) -> None:
        """Refuse a layout whose goal cannot be reached from the start. Every direction has a
        positive probability under some action for any ``prob_drift`` in [0, 0.5], so
        reachability in the move graph is reachability in the MDP."""
        reached = {self.pos_to_state(self.start_pos)}
        frontier = list(reached)
        while frontier:
            new = {int(s) for s in self.move_table[frontier].ravel()} - reached
            reached |= new
            frontier = list(new)
        if self.pos_to_state(self.goal_pos) not in reached:
            raise ValueError(
                f"layout: the goal {self.goal_pos} cannot be reached from the start "
                f"{self.start_pos} (obstacles wall it off); every layout needs a path"
            )

    def is_valid_pos(self, pos: Position) -> bool:
        """Inside the grid and not an obstacle."""
        r, c = pos
        inside = 0 <= r < self.grid_size and 0 <= c < self.grid_size
        return bool(inside and not self.obstacle_mask[r, c])

    def pos_to_state(self, pos: Position) -> int:
        """State index ``row * grid_size + col`` of a position inside the grid."""
        r, c = pos
        if not (0 <= r < self.grid_size and 0 <= c < self.grid_size):
            raise ValueError(
                f"position {pos} is outside the {self.grid_size}x{self.grid_size} grid"
            )
        return int(r) * self.grid_size + int(c)

    def state_to_pos(self, state: int) -> Position:
        """``(row, col)`` of a state index (the inverse of :meth:`pos_to_state`)."""
        state = self.check_state(state)
        return divmod(state, self.grid_size)

    def check_action(self, action: Any) -> int:
        """``action`` as a Python int, or a ValueError naming the allowed range."""
        if isinstance(action, bool) or not isinstance(action, numbers.Integral):
            raise ValueError(f"action must be an integer in 0..3, got {action!r}")
        if not 0 <= action < self.action_space:
            raise ValueError(f"action must be in 0..3 (UP, RIGHT, DOWN, LEFT), got {action}")
        return int(action)

    def check_state(self, state: Any) -> int:
        """``state`` as a Python int, or a ValueError naming the allowed range."""
        if isinstance(state, bool) or not isinstance(state, numbers.Integral):
            raise ValueError(f"state must be an integer index, got {state!r}")
        if not 0 <= state < self.n_states:
            raise ValueError(f"state must be in 0..{self.n_states - 1}, got {state}")
        return int(state)

    # The course interface names these three with a leading underscore.
    def _is_valid_pos(self, pos: Position) -> bool:
        """Same as :meth:`is_valid_pos` (the course's name)."""
        return self.is_valid_pos(pos)

    def _pos_to_state(self, pos: Position) -> int:
        """Same as :meth:`pos_to_state` (the course's name)."""
        return self.pos_to_state(pos)

    def _state_to_pos(self, state: int) -> Position:
        """Same as :meth:`state_to_pos` (the course's name)."""
        return self.state_to_pos(state)

    # ------------------------------------------------------------------ display
    def render(self, value_function: np.ndarray | None = None) -> None:
        """Print the grid (A agent, G goal, # obstacle, P penalty), or the values per cell."""
        lines = []
        for r in range(self.grid_size):
            cells = []
            for c in range(self.grid_size):
                if value_function is not None and not self.obstacle_mask[r, c]:
                    cells.append(f"{float(value_function[r * self.grid_size + c]):7.2f}")
                    continue
                symbol = self.layout[r][c].replace("S", ".")
                if (r, c) == self.current_pos and value_function is None:
                    symbol = "A"
                cells.append(f"{symbol:>7}" if value_function is not None else symbol)
            lines.append(" ".join(cells))
        print("\n".join(lines))
