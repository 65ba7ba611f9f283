"""Experience replay for the two agents' joint transitions (s_A, s_B, a_A, a_B, c_A, c_B, r,
s'_A, s'_B, done): the course's file. ``ReplayBuffer`` is the core's uniform buffer
(``replay.py``, the one the trainer learns from) with the course's ``push`` and ``sample`` and
the checks of what a caller pushes by hand; ``PrioritizedReplayBuffer`` samples by
priority^alpha (course interface; no training run uses it).
"""

from __future__ import annotations

import numpy as np
import replay
from grid_maps import NUM_ACTIONS, positive_int
from replay import TRANSITION_FIELDS, stored_name

__all__ = ["TRANSITION_FIELDS", "PrioritizedReplayBuffer", "ReplayBuffer", "SumTree"]


STATE_FIELDS = ("state_A", "state_B", "next_state_A", "next_state_B")


def check_transitions(arrays: dict[str, np.ndarray]) -> None:
    """Refuse B transitions whose required fields are malformed, naming the field: states
    not (B, D) finite with one D for all four, actions not integers in 0..NUM_ACTIONS-1,
    messages outside [0, 1], rewards not finite, done not boolean (bool or 0/1)."""
    states = [arrays[name] for name in STATE_FIELDS]
    for name, value in zip(STATE_FIELDS, states, strict=True):
        if value.ndim != 2 or value.shape[1] == 0 or value.shape[1:] != states[0].shape[1:]:
            raise ValueError(
                f"{name} must be one observation vector per transition with the size of "
                f"state_A {states[0].shape[1:]}, got per-transition shape {value.shape[1:]}"
            )
        if not np.issubdtype(value.dtype, np.number) or not np.isfinite(value).all():
            raise ValueError(f"{name} must hold finite numbers")
    for name in TRANSITION_FIELDS:
        if name not in STATE_FIELDS and arrays[name].ndim != 1:
            raise ValueError(
                f"{name} must be one number per transition, got per-transition shape "
                f"{arrays[name].shape[1:]}"
            )
    for name in ("action_A", "action_B"):
        value = arrays[name]
        numeric = np.issubdtype(value.dtype, np.number) and value.dtype != np.bool_
        if not (numeric and np.all(np.mod(value, 1) == 0)):
            raise ValueError(f"{name} must be integer actions, got {value[:5].tolist()}")
        if value.min() < 0 or value.max() >= NUM_ACTIONS:
            raise ValueError(f"{name} must lie in 0..{NUM_ACTIONS - 1}, got {value[:5].tolist()}")
    for name in ("comm_A", "comm_B"):
        value = arrays[name]
        if not np.issubdtype(value.dtype, np.number) or not ((value >= 0) & (value <= 1)).all():
            raise ValueError(f"{name} must be a message in [0, 1], got {value[:5].tolist()}")
    reward = arrays["reward"]
    if not np.issubdtype(reward.dtype, np.number) or not np.isfinite(reward).all():
        raise ValueError(f"reward must be a finite number, got {reward[:5].tolist()}")
    done = arrays["done"]
    if done.dtype != np.bool_ and not (
        np.issubdtype(done.dtype, np.number) and np.isin(done, (0, 1)).all()
    ):
        raise ValueError(f"done must be boolean (True/False or 0/1), got {done[:5].tolist()}")


def as_array(name: str, value: object) -> np.ndarray:
    """``value`` as an array; a tensor that requires grad is refused by name."""
    if type(value) is np.ndarray:  # the common case, nothing to convert or check
        return value
    if getattr(value, "requires_grad", False):
        raise ValueError(
            f"{name} is a tensor that requires grad; store a plain number (.item() or .detach())"
        )
    try:
        return np.asarray(value)
    except (TypeError, ValueError, RuntimeError) as error:
        raise ValueError(f"{name} is not an array of numbers: {error}") from error


class ReplayBuffer(replay.ReplayBuffer):
    """The core's uniform buffer (:class:`replay.ReplayBuffer`) with the course's interface:
    :meth:`push` one transition, :meth:`sample` the ten fields; every push is checked
    (:func:`check_transitions`), so a malformed transition is refused by name."""

    def push(
        self,
        state_A,
        state_B,
        action_A,
        action_B,
        comm_A,
        comm_B,
        reward,
        next_state_A,
        next_state_B,
        done,
        **extras,
    ) -> None:
        """Store one transition: states (obs_dim,), the rest scalars; ``extras`` likewise
        one transition's worth each."""
        values = (state_A, state_B, action_A, action_B, comm_A, comm_B, reward)
        values += (next_state_A, next_state_B, done)
        fields = dict(zip(TRANSITION_FIELDS, values, strict=True)) | extras
        self.push_batch(**{name: as_array(name, value)[None] for name, value in fields.items()})

    def push_batch(self, **arrays: np.ndarray) -> np.ndarray:
        """:meth:`replay.ReplayBuffer.push_batch` of the fields as arrays (a tensor that
        requires grad refused by name), each push's values checked (:func:`check_transitions`)."""
        return super().push_batch(**{name: as_array(name, v) for name, v in arrays.items()})

    def _check_transitions(self, arrays: dict[str, np.ndarray]) -> None:
        check_transitions(arrays)

    def sample(self, batch_size: int) -> tuple[np.ndarray, ...]:
        """Uniform sample with replacement: the ten required arrays in interface order,
        states (B, obs_dim) float32, actions (B,) int64, the rest (B,) float32."""
        return self.fields_at(self.sample_indices(batch_size))

    def fields_at(self, indices: np.ndarray) -> tuple[np.ndarray, ...]:
        """The ten required fields at slots ``indices``, in interface order."""
        stored = self.get(indices)
        return tuple(
            stored[stored_name(name)]["AB".index(name[-1])]
            if name.endswith(("_A", "_B"))
            else stored[name]
            for name in TRANSITION_FIELDS
        )


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
