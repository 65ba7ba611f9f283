"""Experience replay of the two agents' joint transitions, and the batch the learner reads.

A transition holds the course's ten fields (s_A, s_B, a_A, a_B, c_A, c_B, r, s'_A, s'_B, done)
and any extras the learner stores with them (the trainer: the observations one step before s
for DIAL, the n-step discount, the observations one step before s'). The buffer keeps one
array per field, A's and B's side by side with the agent axis first (``state``: (2, capacity,
D)), so a sample of B transitions is one gather per field and already the (2, B, D) block
that both agents' networks take in one pass (:func:`sample_batch`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from grid_maps import positive_int

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


def stored_name(field: str) -> str:
    """The array a field lives in: ``state_A`` and ``state_B`` both in ``state``."""
    return field[:-2] if field.endswith(("_A", "_B")) else field


class ReplayBuffer:
    """Uniform replay over the last ``capacity`` joint transitions; ``seed`` seeds sampling.

    The first push fixes the fields and their shapes (actions int64, the rest float32). One
    way in, :meth:`push_batch`; one way out, :meth:`get`. The course's
    ``replay_buffer.ReplayBuffer`` adds ``push``, ``sample`` and checks of hand-made pushes.
    """

    def __init__(self, capacity: int = 10000, seed: int | None = None) -> None:
        self.capacity = positive_int(capacity, "capacity")
        self._rng = np.random.default_rng(seed)
        # stored name -> (capacity, ...), or (2, capacity, ...) for a pair of agent fields
        self._arrays: dict[str, np.ndarray] = {}
        self.field_names: tuple[str, ...] = ()  # set by the first push: the ten, then extras
        self._paired: set[str] = set()  # stored names of the A/B pairs (agent axis first)
        self._size = 0
        self._next_slot = 0

    def __len__(self) -> int:
        return self._size

    def push_batch(self, **arrays: np.ndarray) -> np.ndarray:
        """Store B transitions: the ten required fields and any extras as keywords, each an
        array with leading dimension B (states (B, obs_dim), actions (B,), ...). If B exceeds
        the capacity only the last ``capacity`` are kept. Returns the slots written (B',)."""
        missing = [name for name in TRANSITION_FIELDS if name not in arrays]
        if missing:
            raise ValueError(f"push_batch is missing required fields {missing}")
        lengths = {value.shape[0] if value.ndim else 0 for value in arrays.values()}
        if len(lengths) != 1 or 0 in lengths:
            raise ValueError(
                "every field needs the same non-zero leading (batch) dimension; "
                f"got shapes { {name: a.shape for name, a in arrays.items()} }"
            )
        self._check_transitions(arrays)
        if not self._arrays:
            self._allocate(arrays)
        self._check_like_first_push(arrays)
        count = min(lengths.pop(), self.capacity)
        slots = (self._next_slot + np.arange(count)) % self.capacity
        for name, value in arrays.items():
            target = self._arrays[stored_name(name)]
            if name.endswith(("_A", "_B")):
                target = target["AB".index(name[-1])]
            target[slots] = value[-count:]
        self._next_slot = int(slots[-1] + 1) % self.capacity
        self._size = min(self._size + count, self.capacity)
        self._stored(slots)
        return slots

    def _allocate(self, arrays: dict[str, np.ndarray]) -> None:
        """Fix the fields by those of the first push, with their per-transition shapes."""
        extras = sorted(set(arrays) - set(TRANSITION_FIELDS))
        fields = self.field_names = (*TRANSITION_FIELDS, *extras)
        self._paired = {stored_name(name) for name in fields if name.endswith(("_A", "_B"))}
        for name in fields:
            dtype = np.int64 if stored_name(name) == "action" else np.float32
            agents = (2,) if name.endswith(("_A", "_B")) else ()
            shape = (*agents, self.capacity, *arrays[name].shape[1:])
            self._arrays.setdefault(stored_name(name), np.zeros(shape, dtype))

    def _check_like_first_push(self, arrays: dict[str, np.ndarray]) -> None:
        if set(arrays) != set(self.field_names):
            raise ValueError(
                f"fields {sorted(arrays)} differ from those of the first push "
                f"{sorted(self.field_names)}"
            )
        for name, value in arrays.items():
            stored = self._arrays[stored_name(name)]
            shape = stored.shape[2:] if name.endswith(("_A", "_B")) else stored.shape[1:]
            if value.shape[1:] != shape:
                raise ValueError(f"{name} has per-transition shape {value.shape[1:]}, not {shape}")

    def _check_transitions(self, arrays: dict[str, np.ndarray]) -> None:
        """Hook: check a push's values (the course's buffer does; the trainer's come checked)."""

    def _stored(self, slots: np.ndarray) -> None:
        """Called with the slots of every push (prioritised replay sets their priority)."""

    def _draw_indices(self, batch_size: int) -> np.ndarray:
        """``batch_size`` stored slots, uniformly with replacement."""
        return self._rng.integers(self._size, size=batch_size)

    def sample_indices(self, batch_size: int) -> np.ndarray:
        """Draw ``batch_size`` stored slots (B,) int64."""
        batch_size = positive_int(batch_size, "batch_size")
        if batch_size > self._size:
            raise ValueError(f"cannot sample {batch_size} transitions: it holds {self._size}")
        return self._draw_indices(batch_size)

    def get(self, indices: np.ndarray) -> dict[str, np.ndarray]:
        """Every stored array at slots ``indices`` (B,), by stored name: a pair of agent
        fields (2, B, ...) (``state``, ``action``...), the others (B, ...)."""
        return {
            name: np.take(values, indices, axis=1 if name in self._paired else 0)
            for name, values in self._arrays.items()
        }


@dataclass
class TransitionBatch:
    """B joint transitions as tensors, agent axis first (A, then B)."""

    obs: torch.Tensor  # (2, B, D) observations
    next_obs: torch.Tensor  # (2, B, D) the observations the TD target bootstraps from
    last_obs: torch.Tensor  # (2, B, D) observations one step before next_obs (= obs if n = 1)
    prev_obs: torch.Tensor  # (2, B, D) each agent's observation one step earlier (DIAL)
    has_prev: torch.Tensor  # (B,) 1.0 where prev_obs is stored, else 0.0
    actions: torch.Tensor  # (2, B) int64
    reward: torch.Tensor  # (B,) the team reward (k-step discounted)
    done: torch.Tensor  # (B,) 1.0 where both agents reached the target (terminal)
    discount: torch.Tensor  # (B,) γ^k of the k-step return, 0 where terminal


def sample_batch(buffer: ReplayBuffer, batch_size: int, gamma: float) -> TransitionBatch:
    """``batch_size`` transitions of ``buffer`` as tensors. Fields a transition pushed by hand
    lacks: no previous observation (``has_prev`` 0), ``last_obs`` = ``obs`` and d = γ (1 − done)."""
    stored = {
        k: torch.from_numpy(v) for k, v in buffer.get(buffer.sample_indices(batch_size)).items()
    }
    obs, done = stored["state"], stored["done"]
    return TransitionBatch(
        obs=obs,
        next_obs=stored["next_state"],
        last_obs=stored.get("last_state", obs),
        prev_obs=stored.get("prev_state", torch.zeros_like(obs)),
        has_prev=stored.get("has_prev", torch.zeros_like(done)),
        actions=stored["action"],
        reward=stored["reward"],
        done=done,
        discount=stored["discount"] if "discount" in stored else gamma * (1.0 - done),
    )
