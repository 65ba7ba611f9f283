"""Experience replay of the two agents' joint transitions, and the batch the learner reads.
The course's ``replay_buffer.ReplayBuffer`` is this buffer.

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
from vector_env import NUM_ACTIONS, positive_int

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


class ReplayBuffer:
    """Uniform replay over the last ``capacity`` joint transitions; ``seed`` seeds sampling.

    The first push fixes the fields and their shapes (actions int64, the rest float32). The
    learner pushes many at once (:meth:`push_batch`) and reads by slot (:meth:`get`); the
    course's interface pushes one (:meth:`push`, every value checked) and samples the ten
    fields (:meth:`sample`). A learner's buffer (``gamma`` given) also keeps, per transition,
    the n-step discount and the observations one step before s and s' (DIAL); a transition
    pushed by hand gets them as a one-step transition without a previous observation.
    """

    def __init__(
        self, capacity: int = 10000, seed: int | None = None, gamma: float | None = None
    ) -> None:
        self.capacity = positive_int(capacity, "capacity")
        self.gamma = gamma
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
        arrays = {name: as_array(name, value)[None] for name, value in fields.items()}
        check_transitions(arrays)
        if self.gamma is not None and not extras:  # the learner's fields of a one-step push
            arrays |= self.one_step_fields(arrays)
        self.push_batch(**arrays)

    def one_step_fields(self, arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """What the learner keeps beside the ten fields, for one-step transitions without a
        previous observation: d = γ (1 − done), s' bootstrapped from s, no DIAL splice."""
        done = arrays["done"].astype(np.float32)
        return {
            "discount": (self.gamma * (1.0 - done)).astype(np.float32),
            "has_prev": np.zeros_like(done),
            **{f"last_state_{a}": arrays[f"state_{a}"] for a in "AB"},
            **{f"prev_state_{a}": np.zeros_like(arrays[f"state_{a}"]) for a in "AB"},
        }

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
