"""n-step transitions from the steps of N parallel episodes, for the replay buffer."""

from __future__ import annotations

from collections import deque

import numpy as np
from replay_buffer import _positive_int


class NStepWindow:
    """Turns the steps of N parallel episodes into n-step transitions.

    The transition that starts at step t of an episode carries the discounted reward
    R = r_t + γ r_{t+1} + ... + γ^(k-1) r_{t+k-1}, the observation s_{t+k} it bootstraps
    from, the observation s_{t+k-1} one step before it (whose sender's message s_{t+k}
    holds), and the discount γ^k, or 0 if the episode terminated within those k steps. k is
    n, or fewer where the episode ends (terminal or cut off) before t + n. A transition
    leaves the window at step t + k - 1; with n = 1 every step is its own transition at once.
    """

    def __init__(self, n_step: int, gamma: float, n_envs: int) -> None:
        self.n_step, self.gamma = _positive_int(n_step, "n_step"), float(gamma)
        self.starts: deque[dict[str, np.ndarray]] = deque(maxlen=self.n_step)  # newest last
        self.returns: deque[np.ndarray] = deque(maxlen=self.n_step)  # (N,) float64 each
        self.in_episode = np.zeros(n_envs, np.int64)  # window steps of each running episode

    def add(
        self, start: dict[str, np.ndarray], reward: np.ndarray, next_obs: np.ndarray,
        obs: np.ndarray, terminated: np.ndarray, finished: np.ndarray,
    ) -> dict[str, np.ndarray]:  # fmt: skip
        """One step of the N episodes: ``start`` the fields of the transitions starting now
        (state, action, message, ... each (N, ...)), ``reward`` (N,), the observations
        after (``next_obs``) and before (``obs``) the step (N, 2, D), ``terminated`` and
        ``finished`` (terminated or cut off) (N,) bool. Returns the transitions that are
        complete, oldest start first, as replay fields (``last_state_*`` only for n > 1: with
        one step it is the state); empty if none."""
        for age, returns in enumerate(reversed(self.returns), start=1):
            returns += self.gamma**age * reward
        self.starts.append(start)
        self.returns.append(np.asarray(reward, dtype=np.float64).copy())
        self.in_episode = np.minimum(self.in_episode + 1, self.n_step)
        parts = []
        for lag in range(len(self.starts) - 1, -1, -1):  # steps since the transition began
            due = (lag < self.in_episode) & (finished | (lag == self.n_step - 1))
            if not due.any():
                continue
            rows = slice(None) if due.all() else np.flatnonzero(due)
            fields = {name: value[rows] for name, value in self.starts[-1 - lag].items()}
            fields |= dict(
                reward=self.returns[-1 - lag][rows].astype(np.float32),
                next_state_A=next_obs[rows, 0], next_state_B=next_obs[rows, 1],
                done=terminated[rows],
            )  # fmt: skip
            discount = np.where(terminated[rows], 0.0, self.gamma ** (lag + 1))
            fields["discount"] = discount.astype(np.float32)
            if self.n_step > 1:
                fields |= dict(last_state_A=obs[rows, 0], last_state_B=obs[rows, 1])
            parts.append(fields)
        self.in_episode[finished] = 0
        if len(parts) == 1:
            return parts[0]
        return (
            {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
            if parts
            else {}
        )
