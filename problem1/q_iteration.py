"""Q-iteration: ``Q_{k+1}(s,a) = sum_s' P(s'|s,a) [R(s,a,s') + gamma max_a' Q_k(s',a')]``."""

from __future__ import annotations

import numpy as np
from environment import check_positive_integer
from tabular_model import DynamicProgrammingSolver, check_finite


class QIteration(DynamicProgrammingSolver):
    """Synchronous Q-iteration on the same tabular model and backup as value iteration.

    Q-values start at zero; ``solve`` stops at the first sweep whose sup-norm change
    over all state-action pairs is below ``epsilon``.
    """

    def solve(self, max_iterations: int = 1000) -> tuple[np.ndarray, int]:
        """Return ``(q_values (S, A), iterations)``; ``self.history`` holds each sweep's change."""
        max_iterations = check_positive_integer(max_iterations, "max_iterations")
        q_values = np.zeros((self.n_states, self.n_actions))
        self.history = []
        for _ in range(max_iterations):
            # Bellman optimality update of every pair at once:
            # Q_new(s, a) = sum_k p_k [r_k + gamma * max_a' Q(s'_k, a')] over the 3 outcomes k
            new_q_values = self.model.action_values(q_values.max(axis=1), self.gamma)
            change = float(np.max(np.abs(new_q_values - q_values)))  # sup-norm ||Q_new - Q||
            self.history.append(change)
            q_values = new_q_values
            if change < self.epsilon:
                break
        return q_values, len(self.history)

    def bellman_update(self, state: int, action: int, q_values: np.ndarray) -> float:
        """The backed-up value of one state-action pair under ``q_values``."""
        state, action = self.env.check_state(state), self.env.check_action(action)
        values = self.extract_values(q_values)
        return float(self.model.action_values(values, self.gamma, state)[action])

    def extract_policy(self, q_values: np.ndarray) -> np.ndarray:
        """``(S,)`` int64 greedy actions."""
        return self.model.greedy_policy(q_values)

    def extract_values(self, q_values: np.ndarray) -> np.ndarray:
        """``(S,)`` state values ``max_a Q(s, a)``."""
        return self._checked(q_values).max(axis=1)

    def compute_bellman_error(self, q_values: np.ndarray) -> float:
        """Bellman residual ``max_{s,a} |(T Q)(s,a) - Q(s,a)|``."""
        q_values = self._checked(q_values)
        backed_up = self.model.action_values(q_values.max(axis=1), self.gamma)
        return float(np.max(np.abs(backed_up - q_values)))

    def _checked(self, q_values: np.ndarray) -> np.ndarray:
        return check_finite(q_values, "q_values", (self.n_states, self.n_actions))
