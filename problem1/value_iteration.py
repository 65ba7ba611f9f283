"""Value iteration: ``V_{k+1}(s) = max_a sum_s' P(s'|s,a) [R(s,a,s') + gamma V_k(s')]``."""

from __future__ import annotations

import numpy as np
from tabular_model import DynamicProgrammingSolver


class ValueIteration(DynamicProgrammingSolver):
    """Synchronous value iteration on the tabular model of a :class:`GridWorldEnv`.

    Values start at zero; each iteration is one full sweep over all states, and
    ``solve`` stops at the first sweep whose sup-norm change is below ``epsilon``.
    """

    def solve(self, max_iterations: int = 1000) -> tuple[np.ndarray, int]:
        """Return ``(values (S,), iterations)``; ``self.history`` holds each sweep's change."""
        initial = np.zeros(self.n_states)
        return self._iterate(self._sweep, initial, max_iterations)

    def _sweep(self, values: np.ndarray) -> np.ndarray:
        return self.model.action_values(values, self.gamma).max(axis=1)

    def compute_q_values(self, state: int, values: np.ndarray) -> np.ndarray:
        """``(A,)`` one-step look-ahead action values of ``state`` under ``values``."""
        return self.model.action_values(values, self.gamma, self.env._check_state(state))

    def bellman_backup(self, state: int, values: np.ndarray) -> float:
        """The backed-up value ``max_a Q(state, a)`` (0 for a terminal state)."""
        return float(self.compute_q_values(state, values).max())

    def extract_policy(self, values: np.ndarray) -> np.ndarray:
        """``(S,)`` int64 greedy actions with respect to ``values``."""
        return self.model.greedy_policy(self.model.action_values(values, self.gamma))

    def compute_bellman_error(self, values: np.ndarray) -> float:
        """Bellman residual ``max_s |(T V)(s) - V(s)|``."""
        return float(np.max(np.abs(self._sweep(values) - np.asarray(values))))
