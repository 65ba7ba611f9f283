"""Experience replay for the two agents' joint transitions (s_A, s_B, a_A, a_B, c_A, c_B, r,
s'_A, s'_B, done), plus any extras the learner stores with them (the trainer: previous
observations for DIAL, the n-step discount, the observations one step before s').
``ReplayBuffer`` samples uniformly, ``PrioritizedReplayBuffer`` by priority^alpha.
"""

from __future__ import annotations

import numbers

import numpy as np
from grid_maps import NUM_ACTIONS

TRANSITION_FIELDS = (
    "state_A",
    "state_B",
    "action_A",
    "action_B",
    "comm_A",
    "comm_B",
    "reward",
    "next_state_A",
    "next_state_B",
    "done",
)
STATE_FIELDS = ("state_A", "state_B", "next_state_A", "next_state_B")
# Column order of a row: these observation pairs side by side (A then B), then the rest.
PAIRED_FIELDS = (
    "state_A",
    "state_B",
    "next_state_A",
    "next_state_B",
    "prev_state_A",
    "prev_state_B",
    "last_state_A",
    "last_state_B",
)
_INTEGER_FIELDS = ("action_A", "action_B")  # stored as int64; the other required: float32


def _positive_int(value: int, name: str) -> int:
    number = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not (number and 1 <= value == int(value)):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _as_array(name: str, value: object) -> np.ndarray:
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
    for name in _INTEGER_FIELDS:
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


class ReplayBuffer:
    """Uniform replay over the last ``capacity`` joint transitions; ``seed`` seeds sampling.

    One float32 ring (capacity, row width): a transition is a row, a field a block of its
    columns (:attr:`layout`; A's and B's observations side by side, so a learner can view both
    as one (2, B, D) block). The first push fixes the fields and their shapes. One way in,
    :meth:`push_batch`; one way to draw, :meth:`sample_rows`; :meth:`unpack` turns rows back
    into fields. The course's :meth:`push` and :meth:`sample` are built on them.
    """

    def __init__(self, capacity: int = 10000, seed: int | None = None) -> None:
        self.capacity = _positive_int(capacity, "capacity")
        self._rng = np.random.default_rng(seed)
        self._rows = np.zeros((0, 0), np.float32)  # (capacity, row width) after the first push
        self._shapes: dict[str, tuple[int, ...]] = {}  # each field's per-transition shape
        self.layout: dict[str, slice] = {}  # each field's columns in a row
        self._size = 0
        self._next_slot = 0

    def __len__(self) -> int:
        return self._size

    @property
    def field_names(self) -> tuple[str, ...]:
        """The ten required fields, then the extras (empty before the first push)."""
        return tuple(self._shapes)

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
        arguments = locals()  # the ten required fields, by name
        fields = {name: arguments[name] for name in TRANSITION_FIELDS} | extras
        self.push_batch(**{name: _as_array(name, value)[None] for name, value in fields.items()})

    def push_batch(self, *, validate: bool = True, **arrays: np.ndarray) -> np.ndarray:
        """Store B transitions: the ten required fields and any extras as keywords, each
        with leading dimension B (states (B, obs_dim), actions (B,), ...). If B exceeds the
        capacity only the last ``capacity`` are kept. Returns the slots written (B',) int64.
        ``validate=False`` skips :func:`check_transitions` (for a trainer that pushes what
        the environment returned, already checked there)."""
        missing = [name for name in TRANSITION_FIELDS if name not in arrays]
        if missing:
            raise ValueError(f"push_batch is missing required fields {missing}")
        arrays = {name: _as_array(name, value) for name, value in arrays.items()}
        lengths = {value.shape[0] if value.ndim else 0 for value in arrays.values()}
        if len(lengths) != 1 or 0 in lengths:
            raise ValueError(
                "every field needs the same non-zero leading (batch) dimension; "
                f"got shapes { {name: a.shape for name, a in arrays.items()} }"
            )
        if validate:
            check_transitions(arrays)
        if not self._shapes:
            self._allocate({name: value.shape[1:] for name, value in arrays.items()})
        if set(arrays) != set(self._shapes):
            raise ValueError(
                f"fields {sorted(arrays)} differ from those of the first push "
                f"{sorted(self._shapes)}"
            )
        for name, value in arrays.items():
            if value.shape[1:] != self._shapes[name]:
                raise ValueError(
                    f"{name} has per-transition shape {value.shape[1:]}, the "
                    f"buffer holds {self._shapes[name]}"
                )
        batch_size = min(lengths.pop(), self.capacity)
        slots = (self._next_slot + np.arange(batch_size)) % self.capacity
        end = self._next_slot + batch_size
        rows = slice(self._next_slot, end) if end <= self.capacity else slots  # no wrap: faster
        for name, value in arrays.items():
            self._rows[rows, self.layout[name]] = value[-batch_size:].reshape(batch_size, -1)
        self._next_slot = int(slots[-1] + 1) % self.capacity
        self._size = min(self._size + batch_size, self.capacity)
        self._stored(slots)
        return slots

    def _stored(self, slots: np.ndarray) -> None:
        """Called with the slots of every push (prioritised replay sets their priority)."""

    def _allocate(self, shapes: dict[str, tuple[int, ...]]) -> None:
        """Fix the fields by their per-transition ``shapes`` and their columns."""
        extras = sorted(set(shapes) - set(TRANSITION_FIELDS))
        self._shapes = {name: shapes[name] for name in (*TRANSITION_FIELDS, *extras)}
        columns = [name for name in PAIRED_FIELDS if name in shapes]
        columns += [name for name in self._shapes if name not in PAIRED_FIELDS]
        width = 0
        for name in columns:
            size = int(np.prod(shapes[name], dtype=np.int64))
            self.layout[name] = slice(width, width + size)
            width += size
        self._rows = np.zeros((self.capacity, width), np.float32)

    def _draw_indices(self, batch_size: int) -> np.ndarray:
        return self._rng.integers(self._size, size=batch_size)

    def _weights(self, indices: np.ndarray) -> np.ndarray:
        """Importance weights (B,) float32 of a drawn sample: all 1 for uniform replay."""
        return np.ones(len(indices), dtype=np.float32)

    def sample_rows(
        self, batch_size: int, out: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Draw ``batch_size`` slots (with replacement) and gather their whole rows (into ``out``
        (batch_size, row width) float32 if given): (rows, weights (B,) float32, slots (B,))."""
        batch_size = _positive_int(batch_size, "batch_size")
        if batch_size > self._size:
            raise ValueError(
                f"cannot sample {batch_size} transitions: the buffer holds {self._size}"
            )
        indices = self._draw_indices(batch_size)
        rows = np.take(self._rows, indices, axis=0, out=out, mode="clip")  # valid: faster
        return rows, self._weights(indices), indices

    def unpack(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        """The fields (required and extras) of packed ``rows`` (B, row width), as copies:
        actions int64, everything else float32."""
        return {
            name: rows[:, self.layout[name]]
            .reshape(len(rows), *shape)
            .astype(np.int64 if name in _INTEGER_FIELDS else np.float32)
            for name, shape in self._shapes.items()
        }

    def get(self, indices: np.ndarray) -> dict[str, np.ndarray]:
        """Every field at slots ``indices`` (B,), as in :meth:`unpack`."""
        return self.unpack(self._rows[indices])

    def sample(self, batch_size: int) -> tuple[np.ndarray, ...]:
        """Uniform sample with replacement: the ten required arrays in interface order,
        states (B, obs_dim) float32, actions (B,) int64, the rest (B,) float32."""
        batch = self.unpack(self.sample_rows(batch_size)[0])
        return tuple(batch[name] for name in TRANSITION_FIELDS)


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
        self.beta_steps = _positive_int(beta_steps, "beta_steps")
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
        probabilities = self._tree.values(indices) / self._tree.total
        weights = (self._size * probabilities) ** -self.beta
        self._samples_drawn += 1
        return (weights / weights.max()).astype(np.float32)

    def sample(self, batch_size: int) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray]:
        """(the ten required arrays as in ReplayBuffer.sample, weights (B,) float32,
        slots (B,) int64 to pass back to :meth:`update_priorities`)."""
        rows, weights, indices = self.sample_rows(batch_size)
        batch = self.unpack(rows)
        return tuple(batch[name] for name in TRANSITION_FIELDS), weights, indices

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
