"""The gridworld as explicit arrays, and the one Bellman backup both solvers use.

Every state-action pair has exactly three outcomes (intended move, drift left,
drift right), so the model is three dense ``(S, A, 3)`` arrays instead of an
``S x S`` matrix per action: a sweep costs ``O(S * A)`` time and memory.
"""

from __future__ import annotations

import numbers
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
        terminal[env.pos_to_state(env.goal_pos)] = True
        absorbing = terminal.copy()
        for pos in env.obstacles:
            absorbing[env.pos_to_state(pos)] = True
        return cls(
            next_states, probs, rewards, terminal, absorbing, env.pos_to_state(env.start_pos)
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
        values = check_finite(values, "values", (self.n_states,))
        targets = self.rewards[states] + gamma * values[self.next_states[states]]
        q = np.sum(self.probs[states] * targets, axis=-1)
        return np.where(self.absorbing[states, ..., None], 0.0, q)

    def greedy_policy(self, q_values: np.ndarray) -> np.ndarray:
        """``(S,)`` int64 argmax actions (the first best action on ties; 0 in absorbing states)."""
        q_values = check_finite(q_values, "q_values", (self.n_states, self.n_actions))
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


def check_finite(array: np.ndarray, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``array`` as float64 of the given shape with no NaN or infinity, else a ValueError."""
    array = np.asarray(array, dtype=np.float64)
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite numbers, got NaN or infinity")
    return array


class DynamicProgrammingSolver:
    """What value iteration and Q-iteration share: the tabular model and the parameters.
    Each algorithm writes its own loop in ``solve``; ``history`` records the sup-norm
    change of every sweep of the last ``solve``."""

    def __init__(self, env: GridWorldEnv, gamma: float = 0.95, epsilon: float = 1e-4) -> None:
        if isinstance(gamma, bool) or not isinstance(gamma, numbers.Real) or not 0 <= gamma < 1:
            raise ValueError(f"gamma must lie in [0, 1) for the backup to contract, got {gamma!r}")
        if (
            isinstance(epsilon, bool)
            or not isinstance(epsilon, numbers.Real)
            or not 0 < epsilon < float("inf")
        ):
            raise ValueError(f"epsilon must be a positive finite number, got {epsilon!r}")
        self.env = env
        self.gamma = float(gamma)
        self.epsilon = float(epsilon)
        self.model = TabularModel.from_env(env)
        self.n_states = self.model.n_states
        self.n_actions = self.model.n_actions
        self.history: list[float] = []
