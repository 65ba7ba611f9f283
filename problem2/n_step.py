"""n-step transitions from the steps of N parallel episodes, as replay rows."""

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

    Transitions are rows in the replay buffer's column layout (``layout``: field name ->
    columns, :attr:`replay_buffer.ReplayBuffer.layout`), so that the complete ones are
    stored with one write (:meth:`replay_buffer.ReplayBuffer.push_rows`). The caller gives
    the fields known when a transition starts (state, action, message, ...); the window
    fills ``reward``, ``next_state_A``/``_B``, ``done``, ``discount`` and, for n > 1,
    ``last_state_A``/``_B`` (with one step it is the state).

    Slot layout, e.g. n = 3 steps and N = 2 copies: the row of the transition that starts
    at step s of the run in copy c is ``rows[s % 3, c]`` of ``rows`` (3, 2, width), which is
    slot (s % 3) * 2 + c of the flat view (6, width)::

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
        # The last n steps' rows, a ring over steps: step s of the run is row s % n.
        self.rows = np.zeros((self.n_step, n_envs, 0), np.float32)  # sized at the first add
        self.returns = np.zeros((self.n_step, n_envs))  # discounted rewards so far (float64)
        self.steps_added = 0
        self.in_episode = np.zeros(n_envs, np.int64)  # window steps of each running episode

    def add(
        self, layout: dict[str, slice], start: dict[str, np.ndarray], reward: np.ndarray,
        next_obs: np.ndarray, obs: np.ndarray, terminated: np.ndarray, finished: np.ndarray,
    ) -> np.ndarray:  # fmt: skip
        """One step of the N episodes.

        Args:
            layout: the replay columns of each field (the same at every add).
            start: the fields of the transitions starting now, each (N, columns): written
                from the first column of the field it is named after on (e.g. ``state_A``
                (N, 2 D) fills the columns of state_A, then of state_B).
            reward: (N,) this step's rewards.
            next_obs, obs: (N, 2, D) the observations after and before the step.
            terminated, finished: (N,) bool; finished = terminated or cut off.

        Returns the rows (K, width) float32 of the K transitions that are complete, oldest
        start first (by copy within one start step); K may be 0."""
        n, row = self.n_step, self.steps_added % self.n_step
        copies = len(self.in_episode)
        if not self.rows.shape[2]:  # the first add: a row of the layout's width
            width = max(columns.stop for columns in layout.values())
            self.rows = np.zeros((n, copies, width), np.float32)
        width = self.rows.shape[2]
        held = min(self.steps_added, n - 1)  # earlier steps still in the window
        older = (row - np.arange(1, held + 1)) % n  # their rows, newest first (age 1, 2, ...)
        self.returns[older] += self.discounts[1 : held + 1, None] * reward
        self.returns[row] = reward
        starting = self.rows[row]
        for name, values in start.items():
            block, first = values.reshape(copies, -1), layout[name].start
            starting[:, first : first + block.shape[1]] = block
        self.steps_added += 1
        self.in_episode = np.minimum(self.in_episode + 1, n)
        # Steps since each transition began (oldest first), and which are due now.
        lags = np.arange(held, -1, -1)[:, None]
        due = (lags < self.in_episode) & (finished | (lags == n - 1))
        self.in_episode[finished] = 0
        lag, env = np.nonzero(due)  # in order: oldest start first, then by copy
        lag = held - lag
        slots = (row - lag) % n * copies + env
        rows = np.take(self.rows.reshape(n * copies, width), slots, axis=0)
        if len(env):
            done = terminated[env]
            pairs = {"next_state_A": next_obs} | ({"last_state_A": obs} if n > 1 else {})
            for name, observations in pairs.items():  # A's observation, then B's
                block, first = observations[env].reshape(len(env), -1), layout[name].start
                rows[:, first : first + block.shape[1]] = block
            rows[:, layout["reward"].start] = np.take(self.returns, slots)
            rows[:, layout["done"].start] = done
            rows[:, layout["discount"].start] = np.where(done, 0.0, self.discounts[lag + 1])
        return rows
