"""Teaching the listener: options of the one-step map-pool learner that change what learning
sees, never what is scored.

On maps never seen, a hand-written agent that homes on its partner's distance gains much
from it, while learned one-step agents do not. Four options of the learner (all off by
default, so the map-pool recipe is unchanged without them) target that:

* ``reverse_starts`` (Florensa et al. 2017, reverse curriculum generation): this share of
  the *training* episodes starts with one agent, A or B at random, already on the target
  (:class:`~studies.pool_training.CurriculumEnv`, under ``unseen.PooledOneStepEnv``), so
  the partner's waiting on the target, the state in which the distance is a beacon, is
  common from the first updates.
  Validation and test episodes start as the task's do.
* ``homing_potential`` κ (Ng et al. 1999, potential-based shaping): the learning reward
  gains γ Φ(s') − Φ(s), Φ(s) = κ (1 − d(s)) while exactly one agent stands on the target
  (d the normalised distance between the agents) and 0 otherwise, so Φ = 0 at the terminal
  state. A potential-based term keeps the optimal policies of the reward it is added to;
  the scored reward and success are untouched.
* ``distance_change``: the remembered distance (inside the previous-observation copy of the
  input) is replaced by its change over the last step in cells, (d_t − d_{t−1}) · √(H² + W²),
  0 at an episode start. The same information as d_{t−1}, conditioned for a learner (a step
  of one cell is 0.07 in the raw input); the exported agent computes it from its observation
  and its memory ``h`` (:class:`DistanceChangePolicy`), so the memory contract is unchanged.
* ``listening`` λ (after Eccles et al. 2019, positive listening): a loss
  −λ E‖softmax Q(o, m) − softmax Q(o, m̄)‖₁ that rewards a receiver whose action choice
  depends on the message it hears (m̄: the batch's mean message). Eccles et al. compare
  with a learned average policy of a policy-gradient agent; with Q-learners the softmax of
  the Q-values stands in for the policy and the mean message for the marginal.

:class:`BeaconConfig` holds the options, :class:`BeaconTrainer` applies them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from models import MessagingQNetwork, save_scripted
from multi_agent_env import MultiAgentEnv
from settings import FRACTION, NON_NEGATIVE, boolean, setting
from torch import nn

from studies.one_step.agents import OneStepMemoryPolicy
from studies.one_step.unseen import PooledOneStepEnv, PooledOneStepTrainer
from studies.pool_training import PoolConfig


@dataclass
class BeaconConfig(PoolConfig):
    """The map-pool settings and the listener's training options (all off by default)."""

    reverse_starts: float = setting(0.0, FRACTION)
    """share in [0, 1] of training episodes that start with one agent on the target (reverse
    curriculum); validation and test episodes are untouched"""
    homing_potential: float = setting(0.0, NON_NEGATIVE)
    """kappa >= 0 of the learning-only shaping gamma Phi(s') - Phi(s), Phi = kappa (1 - d) while
    exactly one agent is on the target"""
    distance_change: bool = setting(False, boolean)
    """remember the distance's change over the last step, in cells, instead of its previous value
    (computed inside the exported agent)"""
    listening: float = setting(0.0, NON_NEGATIVE)
    """lambda >= 0 of the positive-listening loss -lambda |softmax Q(o, m) - softmax Q(o, mean
    m)|_1 (comm and full)"""


def with_distance_change(
    inputs: np.ndarray, raw: np.ndarray, scale: float, started: np.ndarray
) -> np.ndarray:
    """``inputs`` (..., 2R + 5) of :func:`agents.augment` with the remembered distance
    (element 2R − 1: the last of the previous-observation copy) replaced by
    (d_t − d_{t−1}) · ``scale``; 0 where ``started`` (..., bool: the episode's first step)."""
    raw_dim = raw.shape[-1]
    remembered = 2 * raw_dim - 3  # patch (R - 2), then the previous copy's last element
    change = (raw[..., -1] - inputs[..., remembered]) * np.float32(scale)
    inputs[..., remembered] = np.where(started, np.float32(0), change)
    return inputs


class DistanceChangeEnv(PooledOneStepEnv):
    """One-step memory inputs on the map pool with the remembered distance as its change in
    cells (:func:`with_distance_change`)."""

    def augment(self, raw: np.ndarray, prev_raw: np.ndarray, prev_action: np.ndarray) -> np.ndarray:
        inputs = super().augment(raw, prev_raw, prev_action)
        return with_distance_change(inputs, raw, float(self._diagonal), prev_action < 0)


class DistanceChangePolicy(nn.Module):
    """An exported one-step memory agent whose network reads the distance's change.

    Same contract as :class:`~studies.one_step.agents.OneStepMemoryPolicy` (``h`` [B, 11]
    the masked previous observation, raw distance included): ``forward`` replaces the
    distance in ``h`` by (obs[:, -1] − h[:, -1]) · ``scale`` (0 where ``prev_action`` is −1)
    before the inner policy sees it, and returns the inner policy's ``h_next``."""

    def __init__(self, network: MessagingQNetwork, mode: str, scale: float) -> None:
        super().__init__()
        self.inner = OneStepMemoryPolicy(network, mode)
        self.register_buffer("scale", torch.tensor(float(scale)))

    @torch.jit.export
    def initial_state(self, batch_size: int) -> torch.Tensor:
        return self.inner.initial_state(batch_size)

    def forward(
        self, obs: torch.Tensor, prev_action: torch.Tensor, h: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        started = (prev_action < 0).unsqueeze(-1)
        change = (obs[:, -1:] - h[:, -1:]) * self.scale
        remembered = torch.cat([h[:, :-1], torch.where(started, 0.0, change)], dim=1)
        return self.inner(obs, prev_action, remembered)


class BeaconTrainer(PooledOneStepTrainer):
    """The one-step map-pool learner with :class:`BeaconConfig`'s options."""

    def __init__(self, env: MultiAgentEnv, cfg: BeaconConfig) -> None:
        if not isinstance(cfg, BeaconConfig):
            raise TypeError(f"BeaconTrainer trains from a BeaconConfig, got {type(cfg).__name__}")
        self.vector_env_class = DistanceChangeEnv if cfg.distance_change else PooledOneStepEnv
        super().__init__(env, cfg)

    def make_vector_env(self, n_envs: int, seed: int | None, validation: bool = False) -> Any:
        """The pool's copies; training copies start a ``reverse_starts`` share of episodes
        with one agent on the target."""
        env = super().make_vector_env(n_envs, seed, validation)
        if not validation:
            env.start_on_target = self.cfg.reverse_starts
        return env

    def homing_potential(self, obs: np.ndarray) -> np.ndarray:
        """Φ (N,) of states ``obs`` (N, 2, D): κ (1 − d) where exactly one agent is on the
        target, else 0 (d, the current distance, is the input's last element)."""
        exactly_one = self.on_target(obs).sum(axis=1) == 1
        return np.where(exactly_one, self.cfg.homing_potential * (1.0 - obs[:, 0, -1]), 0.0)

    def learning_rewards(
        self, rewards: np.ndarray, info: dict[str, np.ndarray], obs: np.ndarray
    ) -> np.ndarray:
        """The pool's learning rewards plus γ Φ(s') − Φ(s) (``homing_potential``), s' the
        state after the step (before an auto-reset; Φ = 0 once both are on the target)."""
        rewards = super().learning_rewards(rewards, info, obs)
        if self.cfg.homing_potential > 0:
            after, before = self.homing_potential(info["final_obs"]), self.homing_potential(obs)
            rewards = (rewards + self.cfg.gamma * after - before).astype(np.float32)
        return rewards

    def td_loss(self, batch: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The core's TD loss, minus λ times the mean L1 change of each receiver's softmax
        policy when its message is replaced by the batch's mean (``listening``), summed over
        both agents, in the modes that hear a message."""
        loss, errors, q_taken = super().td_loss(batch)
        if self.cfg.listening > 0 and bool(self.mask[self.obs_dim - 2]):
            obs = batch.obs * self.mask  # (2, B, D)
            mean_message = obs[..., -2:-1].mean(dim=1, keepdim=True).detach()
            plain = torch.where(self.message_column, mean_message, obs)
            heard, unheard = self.online(obs)[0].softmax(-1), self.online(plain)[0].softmax(-1)
            change = (heard - unheard).abs().sum(-1).mean(dim=1).sum()
            loss = loss - self.cfg.listening * change
        return loss, errors, q_taken

    def export_agent(self, index: int, path: Path) -> Path:
        """Agent ``index`` under the memory contract (the distance's change inside)."""
        if not self.cfg.distance_change:
            return super().export_agent(index, path)
        scale = float(self.rollout.env._diagonal)
        return save_scripted(DistanceChangePolicy(self.online.agent(index), self.mode, scale), path)
