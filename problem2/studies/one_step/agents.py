"""One-step memory: the main recipe's agents with their previous observation and move.

Each agent's network input (27 for the 3 x 3 window) is
    [patch_t (9), o_{t-1} (11, zeros at an episode start), onehot(a_{t-1}) (5, zeros at an
    episode start), message_t, distance_t]
with the current message and distance last, so that the core's mask
(``models.observation_mask(mode, 27)`` zeroes the last two) and the trainer's DIAL message
column (``obs_dim - 2``) still find the current message. ``a_{t-1}`` is the move the agent
made (exploration included). The mode's hidden channels are hidden in both copies of the
observation (:func:`memory_mask`); the stored ``o_{t-1}`` is the raw one.

:class:`OneStepMemoryEnv` builds these inputs, :class:`OneStepMemoryTrainer` trains on them
with the core's loop, and :class:`OneStepMemoryPolicy` is the exported agent under the memory
contract of ``shared/INTERFACES.md``: ``h`` holds the masked previous observation and
``prev_action`` the previous move, so any evaluator runs it on raw 11-dim observations.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from models import MessagingQNetwork, exportable_copy, observation_mask, save_scripted
from torch import nn
from torch.nn import functional as F
from trainer import DQNTrainer
from vector_env import NUM_ACTIONS, VectorMultiAgentEnv, check_step

MEMORY_PARTS = ("observation", "move")  # what one step of memory holds


def memory_mask(mode: str, raw_dim: int = 11, keep: tuple[str, ...] = MEMORY_PARTS) -> np.ndarray:
    """The (2 raw_dim + 5,) float32 input mask of ``mode``: the observation mask (raw_dim,)
    on the current and the previous observation, ones on the one-hot of the previous move;
    a memory part not in ``keep`` (the ablations: the previous move alone, the previous
    observation alone) is zeroed."""
    mask = observation_mask(mode, raw_dim)
    patch = raw_dim - 2
    previous = mask if "observation" in keep else np.zeros_like(mask)
    move = np.full(NUM_ACTIONS, 1.0 if "move" in keep else 0.0, dtype=np.float32)
    return np.concatenate([mask[:patch], previous, move, mask[patch:]]).astype(np.float32)


def augment(raw: np.ndarray, prev_raw: np.ndarray, prev_action: np.ndarray) -> np.ndarray:
    """raw (N, 2, R) and prev_raw (N, 2, R) float32, prev_action (N, 2) int in -1..4 ->
    (N, 2, 2R + 5) float32 inputs in the module docstring's order (one-hot zeros for -1)."""
    patch = raw.shape[-1] - 2
    one_hot = (prev_action[..., None] == np.arange(NUM_ACTIONS)).astype(np.float32)
    parts = [raw[..., :patch], prev_raw, one_hot, raw[..., patch:]]
    return np.concatenate(parts, axis=-1).astype(np.float32, copy=False)


class OneStepMemoryEnv(VectorMultiAgentEnv):
    """The vectorised environment whose observations (N, 2, 27) carry each agent's previous
    raw observation and previous move (:func:`augment`). ``reset``, ``step`` (its ``obs``,
    ``info["final_obs"]`` and the first observation after an auto-reset) and
    ``current_observations`` all return the augmented observation; a copy that starts an
    episode (reset or auto-reset) has zeros as previous observation and move."""

    @property
    def raw_dim(self) -> int:
        """Length of the environment's own observation (w² + 2)."""
        return self.obs_window**2 + 2

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)  # calls reset(), which creates the memory arrays
        self.obs_dim = 2 * self.raw_dim + NUM_ACTIONS

    def _start_episodes(self, rows: np.ndarray, flat: np.ndarray | None = None) -> None:
        super()._start_episodes(rows, flat)
        self._prev_raw[rows] = 0.0
        self._prev_action[rows] = -1

    def augment(self, raw: np.ndarray, prev_raw: np.ndarray, prev_action: np.ndarray) -> np.ndarray:
        """The network inputs of :func:`augment` (a subclass may condition the memory)."""
        return augment(raw, prev_raw, prev_action)

    def current_observations(self) -> np.ndarray:
        """Augmented observations (N, 2, obs_dim) float32 of the current state."""
        raw = self._observe(self._flat, self._messages)
        return self.augment(raw, self._prev_raw, self._prev_action)

    def reset(self, seed: int | None = None, positions: np.ndarray | None = None) -> np.ndarray:
        self._prev_raw = np.zeros((self.n_envs, 2, self.raw_dim), dtype=np.float32)
        self._prev_action = np.full((self.n_envs, 2), -1, dtype=np.int64)
        return super().reset(seed, positions)

    def step(
        self, actions: np.ndarray, messages: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """The core's step (same arguments and returns) with augmented observations."""
        actions, messages = check_step(actions, messages, self.n_envs)
        before = self._observe(self._flat, self._messages)  # o_t, what the agents saw
        saved = self._prev_raw, self._prev_action
        # The memory of the step's result; the auto-reset clears the copies that restart.
        self._prev_raw, self._prev_action = before.copy(), actions.astype(np.int64)
        try:
            raw, rewards, terminated, truncated, info = super().step(actions, messages)
        except ValueError:
            self._prev_raw, self._prev_action = saved
            raise
        info["final_obs"] = self.augment(info["final_obs"], before, actions.astype(np.int64))
        obs = self.augment(raw, self._prev_raw, self._prev_action)
        return obs, rewards, terminated, truncated, info


class OneStepMemoryPolicy(nn.Module):
    """An exported one-step memory agent (memory contract, the mask inside).

    ``forward(obs [B, 11], prev_action [B] int64 (-1 at an episode start), h [B, 11])`` ->
    ``(q [B, 5], message [B, 1], h_next [B, 11])``: the input is
    ``cat(obs[:, :9], h, onehot(prev_action), obs[:, 9:]) * mask`` (27), ``h_next`` the
    masked observation ``obs * obs_mask``; ``initial_state(B)`` is zeros [B, 11]."""

    def __init__(
        self, network: MessagingQNetwork, mode: str, keep: tuple[str, ...] = MEMORY_PARTS
    ) -> None:
        super().__init__()
        network = exportable_copy(network)
        self.network = network
        raw_dim = (network.hidden.weight.shape[1] - NUM_ACTIONS) // 2
        self.register_buffer("mask", torch.from_numpy(memory_mask(mode, raw_dim, keep)))
        self.register_buffer("obs_mask", torch.from_numpy(observation_mask(mode, raw_dim).copy()))

    @torch.jit.export
    def initial_state(self, batch_size: int) -> torch.Tensor:
        return torch.zeros(batch_size, self.obs_mask.shape[0])

    def forward(
        self, obs: torch.Tensor, prev_action: torch.Tensor, h: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        patch = obs.shape[1] - 2
        valid = (prev_action >= 0).unsqueeze(-1).float()
        one_hot = F.one_hot(prev_action.clamp(min=0), self.mask.shape[0] - 2 * obs.shape[1])
        x = torch.cat([obs[:, :patch], h, one_hot.float() * valid, obs[:, patch:]], dim=1)
        q_values, message = self.network(x * self.mask)
        return q_values, message, obs * self.obs_mask


def export_one_step(
    network: MessagingQNetwork, mode: str, path: str | Path, keep: tuple[str, ...] = MEMORY_PARTS
) -> Path:
    """Script ``network`` (input 27) as a :class:`OneStepMemoryPolicy` of ``mode`` and save
    it atomically (``models.save_scripted``: equal weights give byte-identical files)."""
    return save_scripted(OneStepMemoryPolicy(network, mode, keep), path)


class OneStepMemoryTrainer(DQNTrainer):
    """The core learner on :class:`OneStepMemoryEnv`'s 27-dim inputs, with the mode's
    channels hidden in both copies of the observation (:func:`memory_mask`).

    DIAL (comm, full): the core recomputes the *current* message (element ``obs_dim - 2``)
    from the partner's stored previous 27-dim input, with gradient. The remembered message
    (element 18, inside the previous-observation copy) stays as stored: it is the message
    of t − 1, whose sender's input (two steps back) is not stored, so recomputing it would
    need a second previous observation in the replay."""

    vector_env_class = OneStepMemoryEnv
    memory_inputs: tuple[str, ...] = MEMORY_PARTS  # an ablation keeps one of them

    def input_mask(self) -> torch.Tensor:
        """(27,) float32: :func:`memory_mask` of the mode and the memory inputs kept."""
        raw_dim = self.env.obs_window**2 + 2
        return torch.from_numpy(memory_mask(self.mode, raw_dim, self.memory_inputs))

    def export_agent(self, index: int, path: Path) -> Path:
        """Write agent ``index`` as a :class:`OneStepMemoryPolicy`."""
        return export_one_step(self.online.agent(index), self.mode, path, self.memory_inputs)
