"""Experience replay for the two agents' joint transitions (s_A, s_B, a_A, a_B, c_A, c_B, r,
s'_A, s'_B, done): the course's file. ``ReplayBuffer`` is the uniform buffer the learner
learns from (``replay.py``), with the course's ``push`` and ``sample`` and the checks of what
a caller pushes by hand; ``PrioritizedReplayBuffer`` samples by priority^alpha (course
interface; no training run uses it).
"""

from __future__ import annotations

import numpy as np
from replay import TRANSITION_FIELDS, ReplayBuffer
from vector_env import positive_int

__all__ = ["TRANSITION_FIELDS", "PrioritizedReplayBuffer", "ReplayBuffer", "SumTree"]


class SumTree:
    """Binary tree in one array: node 1 is the root, node i has children 2i and 2i + 1,
    and the ``capacity`` leaves start at ``leaf_offset`` (a power of two). Each inner node
    holds the sum of its children, so update and prefix-sum search take O(log n)."""

    def __init__(self, capacity: int) -> None:
        self.depth = max(0, (capacity - 1).bit_length())
        self.leaf_offset = 1 << self.depth
        self.nodes = np.zeros(2 * self.leaf_offset, dtype=np.float64)

    @property
    def total(self) -> float:
        return float(self.nodes[1])

    def values(self, leaves: np.ndarray) -> np.ndarray:
        return self.nodes[np.asarray(leaves) + self.leaf_offset]

    def update(self, leaves: np.ndarray, values: np.ndarray | float) -> None:
        """Set leaves (B,) to ``values`` and recompute their ancestors, level by level."""
        nodes = np.asarray(leaves) + self.leaf_offset
        self.nodes[nodes] = values
        for _ in range(self.depth):
            nodes = np.unique(nodes // 2)
            self.nodes[nodes] = self.nodes[2 * nodes] + self.nodes[2 * nodes + 1]

    def find(self, prefix_sums: np.ndarray) -> np.ndarray:
        """Leaf (B,) whose cumulative range contains each prefix sum in [0, total),
        descending all B searches together one level at a time."""
        remaining = np.array(prefix_sums, dtype=np.float64)
        nodes = np.ones(len(remaining), dtype=np.int64)
        for _ in range(self.depth):
            left = 2 * nodes
            left_sums = self.nodes[left]
            go_right = remaining >= left_sums
            remaining -= np.where(go_right, left_sums, 0.0)
            nodes = left + go_right
        return nodes - self.leaf_offset


class PrioritizedReplayBuffer(ReplayBuffer):
    """Proportional prioritised replay (Schaul et al., 2016).

    Slot i is drawn with probability P(i) = p_i^alpha / sum_k p_k^alpha (stratified: one
    draw from each of B equal slices of the total). New transitions get the largest
    priority seen so far. Importance weights (N · P(i))^(-beta) are divided by their batch
    maximum; beta grows linearly from ``beta_start`` to 1 over ``beta_steps`` samples.
    """

    def __init__(
        self,
        capacity: int = 10000,
        alpha: float = 0.6,
        beta_start: float = 0.4,
        beta_steps: int = 100000,
        seed: int | None = None,
    ) -> None:
        super().__init__(capacity, seed)
        if not alpha >= 0:
            raise ValueError(f"alpha must be >= 0, got {alpha!r}")
        if not 0 <= beta_start <= 1:
            raise ValueError(f"beta_start must be in [0, 1], got {beta_start!r}")
        self.alpha = float(alpha)
        self.beta_start = float(beta_start)
        self.beta_steps = positive_int(beta_steps, "beta_steps")
        self._tree = SumTree(self.capacity)
        self._max_priority = 1.0
        self._samples_drawn = 0

    @property
    def beta(self) -> float:
        """The importance-sampling exponent the next sample will use."""
        progress = min(1.0, self._samples_drawn / self.beta_steps)
        return self.beta_start + (1.0 - self.beta_start) * progress

    def _stored(self, slots: np.ndarray) -> None:
        self._tree.update(slots, self._max_priority**self.alpha)

    def _draw_indices(self, batch_size: int) -> np.ndarray:
        slice_width = self._tree.total / batch_size
        prefix_sums = (np.arange(batch_size) + self._rng.random(batch_size)) * slice_width
        # Rounding can carry a search just past the last stored slot (priority 0).
        return np.minimum(self._tree.find(prefix_sums), self._size - 1)

    def _weights(self, indices: np.ndarray) -> np.ndarray:
        """Importance weights (B,) float32 of a drawn sample, divided by their maximum."""
        probabilities = self._tree.values(indices) / self._tree.total
        weights = (self._size * probabilities) ** -self.beta
        self._samples_drawn += 1
        return (weights / weights.max()).astype(np.float32)

    def sample(self, batch_size: int) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray]:
        """(the ten required arrays as in ReplayBuffer.sample, weights (B,) float32,
        slots (B,) int64 to pass back to :meth:`update_priorities`)."""
        indices = self.sample_indices(batch_size)
        return self.fields_at(indices), self._weights(indices), indices

    def update_priorities(self, indices: np.ndarray, priorities: np.ndarray) -> None:
        """Set the priorities (B,) of slots ``indices`` (B,), e.g. |TD error| + 1e-6.
        Priorities must be positive and finite. A slot that a sample drew more than once
        (sampling is with replacement) gets the largest of its priorities."""
        raw_indices = np.asarray(indices).reshape(-1)
        if raw_indices.dtype == np.bool_ or not (
            np.issubdtype(raw_indices.dtype, np.number) and np.all(np.mod(raw_indices, 1) == 0)
        ):
            raise ValueError(f"indices must be integers, got {raw_indices[:5].tolist()}")
        indices = raw_indices.astype(np.int64)
        priorities = np.asarray(priorities, dtype=np.float64).reshape(-1)
        if indices.shape != priorities.shape:
            raise ValueError(f"{len(indices)} indices but {len(priorities)} priorities")
        if len(indices) and (indices.min() < 0 or indices.max() >= self._size):
            raise ValueError(f"indices must be stored slots in 0..{self._size - 1}")
        if not (np.isfinite(priorities).all() and (priorities > 0).all()):
            raise ValueError("priorities must be positive and finite")
        unique, inverse = np.unique(indices, return_inverse=True)
        largest = np.zeros(len(unique))
        np.maximum.at(largest, inverse, priorities)
        self._tree.update(unique, largest**self.alpha)
        if len(largest):
            self._max_priority = max(self._max_priority, float(largest.max()))
