"""Q-iteration: ``Q_{k+1}(s,a) = sum_s' P(s'|s,a) [R(s,a,s') + gamma max_a' Q_k(s',a')]``."""

from __future__ import annotations

import numpy as np
from tabular_model import DynamicProgrammingSolver


class QIteration(DynamicProgrammingSolver):
    """Synchronous Q-iteration on the same tabular model and backup as value iteration.

    Q-values start at zero; ``solve`` stops at the first sweep whose sup-norm change
    over all state-action pairs is below ``epsilon``.
    """

    def solve(self, max_iterations: int = 1000) -> tuple[np.ndarray, int]:
        """Return ``(q_values (S, A), iterations)``; ``self.history`` holds each sweep's change."""
        initial = np.zeros((self.n_states, self.n_actions))
        return self._iterate(self._sweep, initial, max_iterations)

    def _sweep(self, q_values: np.ndarray) -> np.ndarray:
        return self.model.action_values(self.extract_values(q_values), self.gamma)

    def bellman_update(self, state: int, action: int, q_values: np.ndarray) -> float:
        """The backed-up value of one state-action pair under ``q_values``."""
        state, action = self.env._check_state(state), self.env._check_action(action)
        values = self.extract_values(q_values)
        return float(self.model.action_values(values, self.gamma, state)[action])

    def extract_policy(self, q_values: np.ndarray) -> np.ndarray:
        """``(S,)`` int64 greedy actions."""
        return self.model.greedy_policy(self._check_shape(q_values))

    def extract_values(self, q_values: np.ndarray) -> np.ndarray:
        """``(S,)`` state values ``max_a Q(s, a)``."""
        return self._check_shape(q_values).max(axis=1)

    def compute_bellman_error(self, q_values: np.ndarray) -> float:
        """Bellman residual ``max_{s,a} |(T Q)(s,a) - Q(s,a)|``."""
        return float(np.max(np.abs(self._sweep(q_values) - self._check_shape(q_values))))

    def _check_shape(self, q_values: np.ndarray) -> np.ndarray:
        q_values = np.asarray(q_values, dtype=np.float64)
        expected = (self.n_states, self.n_actions)
        if q_values.shape != expected:
            raise ValueError(f"q_values must have shape {expected}, got {q_values.shape}")
        return q_values
