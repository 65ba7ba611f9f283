"""The gridworld as explicit arrays, and the one Bellman backup both solvers use.

Every state-action pair has exactly three outcomes (intended move, drift left,
drift right), so the model is three dense ``(S, A, 3)`` arrays instead of an
``S x S`` matrix per action: a sweep costs ``O(S * A)`` time and memory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from environment import OUTCOME_DIRECTIONS, GridWorldEnv


@dataclass(frozen=True)
class TabularModel:
    """Arrays describing the MDP of a :class:`GridWorldEnv`.

    Attributes:
        next_states: ``(S, A, 3)`` int, the state each outcome leads to.
        probs: ``(S, A, 3)`` float, the outcome probabilities (sum to 1 over the last axis).
        rewards: ``(S, A, 3)`` float, the reward of each outcome (reward of the cell entered).
        terminal: ``(S,)`` bool, the goal.
        absorbing: ``(S,)`` bool, states with no decision to make (goal and obstacle
            cells, the latter unreachable); their values are fixed at 0.
        start_state: index of the start cell.
    """

    next_states: np.ndarray
    probs: np.ndarray
    rewards: np.ndarray
    terminal: np.ndarray
    absorbing: np.ndarray
    start_state: int

    @classmethod
    def from_env(cls, env: GridWorldEnv) -> TabularModel:
        """Read the model off the environment's move table and cell rewards."""
        next_states = env.move_table[:, OUTCOME_DIRECTIONS]  # (S, 4, 3)
        probs = np.broadcast_to(env.outcome_probs, next_states.shape).copy()
        rewards = env.cell_rewards[next_states]
        terminal = np.zeros(env.n_states, dtype=bool)
        terminal[env._pos_to_state(env.goal_pos)] = True
        absorbing = terminal.copy()
        for pos in env.obstacles:
            absorbing[env._pos_to_state(pos)] = True
        return cls(
            next_states, probs, rewards, terminal, absorbing, env._pos_to_state(env.start_pos)
        )

    @property
    def n_states(self) -> int:
        return self.next_states.shape[0]

    @property
    def n_actions(self) -> int:
        return self.next_states.shape[1]

    def action_values(
        self, values: np.ndarray, gamma: float, states: int | slice | np.ndarray = slice(None)
    ) -> np.ndarray:
        """One Bellman backup: ``Q(s, a) = sum_k p_k [r_k + gamma * V(s'_k)]``.

        Args:
            values: ``(S,)`` state values ``V``.
            gamma: discount factor.
            states: which states to back up (all by default, or one index).

        Returns:
            ``(S, A)`` action values, or ``(A,)`` for a single state; zero in
            absorbing states, whose episode is over.
        """
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (self.n_states,):
            raise ValueError(f"values must have shape ({self.n_states},), got {values.shape}")
        targets = self.rewards[states] + gamma * values[self.next_states[states]]
        q = np.sum(self.probs[states] * targets, axis=-1)
        return np.where(self.absorbing[states, ..., None], 0.0, q)

    def greedy_policy(self, q_values: np.ndarray) -> np.ndarray:
        """``(S,)`` int64 argmax actions (the first best action on ties; 0 in absorbing states)."""
        return np.argmax(q_values, axis=1).astype(np.int64)

    def evaluate_policy(
        self, policy: np.ndarray, gamma: float, outcome_rewards: np.ndarray | None = None
    ) -> np.ndarray:
        """Exact ``V_pi`` (S,) of a deterministic policy by solving ``(I - gamma P_pi) V = R_pi``.

        ``outcome_rewards`` (S, A, 3) replaces the model's rewards, e.g. ones to get the
        expected number of steps to the goal (with ``gamma = 1`` for a policy that
        reaches it). Absorbing states get an all-zero row of ``P_pi``, hence value 0.
        Dense ``S x S`` algebra: meant for verification on small grids only.
        """
        rewards = self.rewards if outcome_rewards is None else outcome_rewards
        rows = np.arange(self.n_states)
        outcomes = self.next_states[rows, policy]  # (S, 3)
        probs = np.where(self.absorbing[:, None], 0.0, self.probs[rows, policy])
        transition = np.zeros((self.n_states, self.n_states))
        np.add.at(transition, (np.repeat(rows, outcomes.shape[1]), outcomes.ravel()), probs.ravel())
        expected_reward = np.sum(probs * rewards[rows, policy], axis=1)
        return np.linalg.solve(np.eye(self.n_states) - gamma * transition, expected_reward)


class DynamicProgrammingSolver:
    """What value iteration and Q-iteration share: the model, the parameters and
    the fixed-point loop that records the sup-norm change of every sweep."""

    def __init__(self, env: GridWorldEnv, gamma: float = 0.95, epsilon: float = 1e-4) -> None:
        if not 0.0 <= gamma < 1.0:
            raise ValueError(f"gamma must lie in [0, 1) for the backup to contract, got {gamma}")
        if not epsilon > 0.0:
            raise ValueError(f"epsilon must be positive, got {epsilon}")
        self.env = env
        self.gamma = float(gamma)
        self.epsilon = float(epsilon)
        self.model = TabularModel.from_env(env)
        self.n_states = self.model.n_states
        self.n_actions = self.model.n_actions
        self.history: list[float] = []

    def _iterate(
        self, sweep: Callable[[np.ndarray], np.ndarray], initial: np.ndarray, max_iterations: int
    ) -> tuple[np.ndarray, int]:
        """Apply ``sweep`` until ``max |new - old| < epsilon`` or ``max_iterations`` sweeps.

        Returns the last iterate and the number of sweeps performed; the change of
        every sweep is kept in ``self.history``.
        """
        if max_iterations < 1:
            raise ValueError(f"max_iterations must be at least 1, got {max_iterations}")
        self.history = []
        current = initial
        for _ in range(max_iterations):
            updated = sweep(current)
            change = float(np.max(np.abs(updated - current)))
            self.history.append(change)
            current = updated
            if change < self.epsilon:
                break
        return current, len(self.history)
