"""Value iteration: ``V_{k+1}(s) = max_a sum_s' P(s'|s,a) [R(s,a,s') + gamma V_k(s')]``."""

from __future__ import annotations

import numpy as np
from environment import check_positive_integer
from tabular_model import DynamicProgrammingSolver


class ValueIteration(DynamicProgrammingSolver):
    """Synchronous value iteration on the tabular model of a :class:`GridWorldEnv`.

    Values start at zero; each iteration is one full sweep over all states, and
    ``solve`` stops at the first sweep whose sup-norm change is below ``epsilon``.
    """

    def solve(self, max_iterations: int = 1000) -> tuple[np.ndarray, int]:
        """Return ``(values (S,), iterations)``; ``self.history`` holds each sweep's change."""
        max_iterations = check_positive_integer(max_iterations, "max_iterations")
        values = np.zeros(self.n_states)
        self.history = []
        for _ in range(max_iterations):
            # Bellman optimality update of every state at once:
            # V_new(s) = max_a sum_k p_k [r_k + gamma * V(s'_k)] over the 3 outcomes k of (s, a)
            new_values = self.model.action_values(values, self.gamma).max(axis=1)
            change = float(np.max(np.abs(new_values - values)))  # sup-norm ||V_new - V||
            self.history.append(change)
            values = new_values
            if change < self.epsilon:
                break
        return values, len(self.history)

    def compute_q_values(self, state: int, values: np.ndarray) -> np.ndarray:
        """``(A,)`` one-step look-ahead action values of ``state`` under ``values``."""
        return self.model.action_values(values, self.gamma, self.env.check_state(state))

    def bellman_backup(self, state: int, values: np.ndarray) -> float:
        """The backed-up value ``max_a Q(state, a)`` (0 for a terminal state)."""
        return float(self.compute_q_values(state, values).max())

    def extract_policy(self, values: np.ndarray) -> np.ndarray:
        """``(S,)`` int64 greedy actions with respect to ``values`` (finite, shape (S,))."""
        return self.model.greedy_policy(self.model.action_values(values, self.gamma))

    def compute_bellman_error(self, values: np.ndarray) -> float:
        """Bellman residual ``max_s |(T V)(s) - V(s)|``."""
        backed_up = self.model.action_values(values, self.gamma).max(axis=1)
        return float(np.max(np.abs(backed_up - np.asarray(values))))
