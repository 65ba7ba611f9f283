"""n-step transitions from the steps of N parallel episodes, for the replay buffer."""

from __future__ import annotations

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

    Slot layout, e.g. n = 3 steps and N = 2 copies: the fields of the transition that starts
    at step s of the run in copy c are held in row s % 3 of ``starts`` (3, 2, ...), which is
    slot (s % 3) * 2 + c of the flat view (6, ...)::

        slot            0    1    2    3    4    5
        row (s % 3)     0    0    1    1    2    2
        copy c          0    1    0    1    0    1
        start step s  0, 3 0, 3 1, 4 1, 4 2, 5 2, 5

    At step 2 the transitions of step 0 are complete (k = 3, slots 0 and 1) and leave, so
    step 3 may reuse row 0. If copy 1 is cut off at step 3, that step returns, oldest start
    first and then by copy: copy 0 from step 1 (slot 2, k = 3), copy 1 from steps 1, 2 and 3
    (slots 3, 5 and 1; k = 3, 2 and 1).
    """

    def __init__(self, n_step: int, gamma: float, n_envs: int) -> None:
        self.n_step, self.gamma = _positive_int(n_step, "n_step"), float(gamma)
        self.discounts = np.array([self.gamma**k for k in range(self.n_step + 1)])  # γ^k
        # The last n steps' fields, a ring over steps: step s of the run is row s % n.
        self.starts: dict[str, np.ndarray] = {}  # each (n, N, ...), allocated at the first add
        self._by_slot: dict[str, np.ndarray] = {}  # the same, (n * N, ...)
        self.returns = np.zeros((self.n_step, n_envs))  # discounted rewards so far (float64)
        self.steps_added = 0
        self.in_episode = np.zeros(n_envs, np.int64)  # window steps of each running episode

    def add(
        self, start: dict[str, np.ndarray], reward: np.ndarray, next_obs: np.ndarray,
        obs: np.ndarray, terminated: np.ndarray, finished: np.ndarray,
    ) -> dict[str, np.ndarray]:  # fmt: skip
        """One step of the N episodes: ``start`` the fields of the transitions starting now
        (state, action, message, ... each (N, ...), each field with the dtype and shape of
        the first add), ``reward`` (N,), the observations after (``next_obs``) and before
        (``obs``) the step (N, 2, D), ``terminated`` and ``finished`` (terminated or cut
        off) (N,) bool. Returns the transitions that are complete, oldest start first (by
        copy within one start step), as replay fields (``last_state_*`` only for n > 1:
        with one step it is the state); empty if none."""
        n, row = self.n_step, self.steps_added % self.n_step
        if not self.starts:
            self.starts = {
                k: np.zeros((n, *np.shape(v)), np.asarray(v).dtype) for k, v in start.items()
            }
            # The same storage indexed by step row * N + copy (np.take on it is fastest).
            self._by_slot = {k: v.reshape(-1, *v.shape[2:]) for k, v in self.starts.items()}
        held = min(self.steps_added, n - 1)  # earlier steps still in the window
        older = (row - np.arange(1, held + 1)) % n  # their rows, newest first (age 1, 2, ...)
        self.returns[older] += self.discounts[1 : held + 1, None] * reward
        self.returns[row] = reward
        for name, value in start.items():
            self.starts[name][row] = value
        self.steps_added += 1
        self.in_episode = np.minimum(self.in_episode + 1, n)
        # Steps since each transition began (oldest first), and which are due now.
        lags = np.arange(held, -1, -1)[:, None]
        due = (lags < self.in_episode) & (finished | (lags == n - 1))
        self.in_episode[finished] = 0
        lag, env = np.nonzero(due)  # in order: oldest start first, then by copy
        if not len(env):
            return {}
        lag = held - lag
        slots = (row - lag) % n * len(self.in_episode) + env
        fields = {name: np.take(values, slots, axis=0) for name, values in self._by_slot.items()}
        after, done = np.take(next_obs, env, axis=0), terminated[env]
        fields |= dict(
            reward=np.take(self.returns, slots).astype(np.float32),
            next_state_A=after[:, 0], next_state_B=after[:, 1], done=done,
            discount=np.where(done, 0.0, self.discounts[lag + 1]).astype(np.float32),
        )  # fmt: skip
        if n > 1:
            before = np.take(obs, env, axis=0)
            fields |= dict(last_state_A=before[:, 0], last_state_B=before[:, 1])
        return fields
