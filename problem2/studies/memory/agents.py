"""Agents with memory: a GRU Q-network with a message head, its TorchScript export by the
memory contract, and a policy function that runs such agents through the one episode loop.

The network reads, at each step t, the masked observation o_t (11) and the one-hot of the
move it made at t − 1 (5; zeros at an episode start):
    x_t = ReLU(W1 [o_t, onehot(a_{t−1})] + b1),   h_t = GRU(x_t, h_{t−1}),   h_{−1} = 0
    Q(·, t) = W_q h_t + b_q,   m_t = sigmoid(w_m · h_t + b_m)
so its hidden vector h can hold what a feedforward agent cannot: whether the last move
brought the agents closer, a heading, whether it has been on the target.

Exported (``export_recurrent``) it keeps the contract of ``shared/INTERFACES.md``:
``initial_state(batch_size) -> (B, H)`` and ``forward(obs (B, 11), prev_action (B,) int64,
h (B, H)) -> (q (B, 5), message (B, 1), h_next (B, H))``, the mode's mask inside.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from models import OBSERVATION_DIM, observation_mask, save_scripted
from rollout import PolicyFn
from settings import TRAINABLE_MODES
from torch import nn
from torch.nn import functional as F
from vector_env import MESSAGE_INDEX, VectorMultiAgentEnv

NUM_ACTIONS = 5
# The 2 x 2 of the channels: the assignment's three ablations and "distance" (message masked).
MEMORY_MODES = TRAINABLE_MODES


def mode_mask(mode: str) -> np.ndarray:
    """The observation mask (11,) float32 of one of ``MEMORY_MODES``."""
    if mode not in MEMORY_MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {MEMORY_MODES}")
    if mode == "distance":
        mask = observation_mask("full").copy()
        mask[MESSAGE_INDEX] = 0.0
        return mask
    return observation_mask(mode)


def one_hot_previous(prev_action: torch.Tensor) -> torch.Tensor:
    """prev_action (...,) int64 in -1..4 -> (..., 5) float32, zeros for -1 (no move yet)."""
    valid = (prev_action >= 0).unsqueeze(-1)
    return F.one_hot(prev_action.clamp(min=0), NUM_ACTIONS).float() * valid


class RecurrentQNetwork(nn.Module):
    """The GRU agent of the module docstring, for training: ``unroll`` runs whole sequences
    through ``nn.GRU`` (one call), ``step`` one time step of many agents."""

    def __init__(self, mode: str, hidden_dim: int = 64, obs_dim: int = OBSERVATION_DIM) -> None:
        super().__init__()
        self.mode, self.hidden_dim = mode, hidden_dim
        self.register_buffer("mask", torch.tensor(mode_mask(mode)))
        self.encoder = nn.Linear(obs_dim + NUM_ACTIONS, hidden_dim)
        self.gru = nn.GRU(hidden_dim, hidden_dim)
        self.q_head = nn.Linear(hidden_dim, NUM_ACTIONS)
        self.message_head = nn.Linear(hidden_dim, 1)

    def unroll(
        self, obs: torch.Tensor, prev_action: torch.Tensor, h0: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """obs (T, B, 11) raw, prev_action (T, B) -> Q (T, B, 5), message logits (T, B) and
        the last state (B, H); ``h0`` (B, H), zeros if None."""
        x = F.relu(self.encoder(torch.cat([obs * self.mask, one_hot_previous(prev_action)], -1)))
        states, last = self.gru(x, None if h0 is None else h0.unsqueeze(0))
        return self.q_head(states), self.message_head(states)[..., 0], last[0]

    def step(
        self, obs: torch.Tensor, prev_action: torch.Tensor, h: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One step: obs (B, 11), prev_action (B,), h (B, H) -> Q (B, 5), logits (B,), h'."""
        q, logits, h_next = self.unroll(obs.unsqueeze(0), prev_action.unsqueeze(0), h)
        return q[0], logits[0], h_next

    def initial_state(self, batch_size: int) -> torch.Tensor:
        return torch.zeros(batch_size, self.hidden_dim)

    def forward(
        self, obs: torch.Tensor, prev_action: torch.Tensor, h: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The memory contract (as exported): Q (B, 5), message (B, 1), h_next (B, H)."""
        q, logits, h_next = self.step(obs, prev_action, h)
        return q, torch.sigmoid(logits).unsqueeze(-1), h_next


class RecurrentPolicy(nn.Module):
    """The exported agent: the same computation as :class:`RecurrentQNetwork` written with
    plain tensors (the GRU gates of ``nn.GRU``: reset, update, new), so that the TorchScript
    file holds weights and code only and the same weights always give the same bytes."""

    def __init__(self, network: RecurrentQNetwork) -> None:
        super().__init__()
        copy = {name: p.detach().clone() for name, p in network.named_parameters()}
        self.register_buffer("mask", network.mask.detach().clone())
        for name, value in copy.items():
            self.register_buffer(name.replace(".", "_"), value)

    @torch.jit.export
    def initial_state(self, batch_size: int) -> torch.Tensor:
        return torch.zeros(batch_size, self.gru_weight_hh_l0.shape[1])

    def forward(
        self, obs: torch.Tensor, prev_action: torch.Tensor, h: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        valid = (prev_action >= 0).unsqueeze(-1).float()
        previous = F.one_hot(prev_action.clamp(min=0), self.q_head_weight.shape[0]).float()
        x = torch.cat([obs * self.mask, previous * valid], -1)
        x = F.relu(F.linear(x, self.encoder_weight, self.encoder_bias))
        gi = F.linear(x, self.gru_weight_ih_l0, self.gru_bias_ih_l0)
        gh = F.linear(h, self.gru_weight_hh_l0, self.gru_bias_hh_l0)
        i_r, i_z, i_n = gi.chunk(3, 1)
        h_r, h_z, h_n = gh.chunk(3, 1)
        reset, update = torch.sigmoid(i_r + h_r), torch.sigmoid(i_z + h_z)
        new = torch.tanh(i_n + reset * h_n)
        h_next = (1.0 - update) * new + update * h
        q = F.linear(h_next, self.q_head_weight, self.q_head_bias)
        message = torch.sigmoid(F.linear(h_next, self.message_head_weight, self.message_head_bias))
        return q, message, h_next


def export_recurrent(network: RecurrentQNetwork, path: str | Path) -> Path:
    """Script ``network`` as a :class:`RecurrentPolicy` and save it atomically
    (:func:`models.save_scripted`: equal weights give byte-identical files)."""
    return save_scripted(RecurrentPolicy(network.cpu()).eval(), path)


def memory_policy(
    agents: tuple[torch.nn.Module, torch.nn.Module],
    env: VectorMultiAgentEnv,
    epsilon: float = 0.0,
    seed: int = 0,
    draws: PolicyFn | None = None,
) -> PolicyFn:
    """A :data:`rollout.PolicyFn` of two memory agents (anything with ``initial_state`` and
    ``forward(obs, prev_action, h)``, e.g. loaded TorchScript files) on the copies of ``env``:
    a copy's state is reset wherever ``env.steps`` is 0 (an episode start). ε-greedy with its
    own generator, or with exploration drawn outside: ``draws`` returns actions (N, 2), the
    random move where an agent explores now and −1 elsewhere. The action fed back is the one
    taken."""
    rng = np.random.default_rng(seed)
    n = env.n_envs
    states = [agent.initial_state(n) for agent in agents]
    previous = torch.full((n, 2), -1, dtype=torch.int64)

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        starting = torch.from_numpy(env.steps == 0)
        observations = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        q_values, messages = [], []
        with torch.inference_mode():
            for i, agent in enumerate(agents):
                h = torch.where(starting[:, None], agent.initial_state(n), states[i])
                prev = torch.where(starting, -1, previous[:, i])
                q, message, states[i] = agent(observations[:, i], prev, h)
                q_values.append(q.numpy())
                messages.append(message[:, 0].numpy())
        actions = np.stack(q_values, axis=1).argmax(axis=-1)
        if draws is not None:
            drawn, _ = draws(obs, positions)
            actions = np.where(drawn >= 0, drawn, actions)
        elif epsilon > 0:
            explore = rng.random(actions.shape) < epsilon
            actions = np.where(explore, rng.integers(0, NUM_ACTIONS, actions.shape), actions)
        previous.copy_(torch.from_numpy(actions))
        return actions, np.stack(messages, axis=1)

    return act
