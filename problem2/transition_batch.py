"""A replay batch as the learner reads it: B joint transitions as tensors, agent axis first,
viewed in one block of replay rows gathered with a single copy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from replay_buffer import ReplayBuffer


@dataclass
class TransitionBatch:
    """B joint transitions as tensors, agent axis first (A, then B): views of one gathered
    block of replay rows."""

    obs: torch.Tensor  # (2, B, D) observations
    next_obs: torch.Tensor  # (2, B, D) the observations the TD target bootstraps from
    last_obs: torch.Tensor  # (2, B, D) observations one step before next_obs (= obs if n = 1)
    prev_obs: torch.Tensor  # (2, B, D) each agent's observation one step earlier (DIAL)
    has_prev: torch.Tensor  # (B,) 1.0 where prev_obs is stored, else 0.0
    actions: torch.Tensor  # (2, B) int64
    reward: torch.Tensor  # (B,) the team reward (k-step discounted)
    done: torch.Tensor  # (B,) 1.0 where both agents reached the target (terminal)
    discount: torch.Tensor  # (B,) γ^k of the k-step return, 0 where terminal
    weights: torch.Tensor  # (B,) importance weights (ones without prioritised replay)

    @classmethod
    def of_rows(cls, rows: torch.Tensor, layout: dict[str, slice], obs_dim: int) -> TransitionBatch:
        """Views of ``rows`` (B, row width) in the replay buffer's ``layout``. Fields the
        rows lack (transitions pushed by hand) are zeros, ``last_obs`` then ``obs``.
        ``actions`` is int64, so a copy that :meth:`BatchSampler.sample` fills."""
        b = rows.shape[0]

        def pair(name_a: str) -> torch.Tensor:  # columns of X_A then X_B -> (2, B, D)
            if name_a not in layout:
                return torch.zeros(2, b, obs_dim)
            first = layout[name_a].start
            return rows[:, first : first + 2 * obs_dim].view(b, 2, obs_dim).transpose(0, 1)

        def column(name: str) -> torch.Tensor:
            return rows[:, layout[name].start] if name in layout else torch.zeros(b)

        obs = pair("state_A")
        return cls(
            obs=obs,
            next_obs=pair("next_state_A"),
            last_obs=pair("last_state_A") if "last_state_A" in layout else obs,
            prev_obs=pair("prev_state_A"),
            has_prev=column("has_prev"),
            actions=torch.zeros(2, b, dtype=torch.int64),
            reward=column("reward"),
            done=column("done"),
            discount=column("discount"),
            weights=torch.ones(b),
        )


class BatchSampler:
    """Draws batches from a replay buffer (uniform or prioritised) into one block of rows
    that it reuses from update to update: one gather, no allocation per update. A batch
    is valid until the next draw."""

    def __init__(self, obs_dim: int, gamma: float) -> None:
        self.obs_dim, self.gamma = obs_dim, gamma
        self._block: tuple[tuple, torch.Tensor, TransitionBatch] | None = None

    def sample(self, buffer: ReplayBuffer, batch_size: int) -> tuple[TransitionBatch, np.ndarray]:
        """``batch_size`` transitions of ``buffer``: the batch and the replay slots (B,) they
        came from. Transitions pushed by hand (no stored discount) get d = γ (1 − done)."""
        layout = buffer.layout
        key = (batch_size, tuple(layout))
        if self._block is None or self._block[0] != key:
            rows = torch.empty(batch_size, max(columns.stop for columns in layout.values()))
            self._block = (key, rows, TransitionBatch.of_rows(rows, layout, self.obs_dim))
        _, rows, batch = self._block
        _, weights, slots = buffer.sample_rows(batch_size, rows.numpy())
        first = layout["action_A"].start
        batch.actions.copy_(rows[:, first : first + 2].T)  # A's column then B's
        if "discount" not in layout:
            batch.discount.copy_(self.gamma * (1.0 - batch.done))
        batch.weights.copy_(torch.from_numpy(weights))  # all 1 for uniform replay
        return batch, slots
