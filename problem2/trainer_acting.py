"""How :class:`trainer.MultiAgentTrainer` acts: the N environment copies it plays
(:class:`Rollout`), ε-greedy actions with DIAL noise on the messages, and its policy for
evaluation (:meth:`TrainerActing.policy`, a ``rollout.PolicyFn``).

:class:`TrainerActing` is a base class of ``MultiAgentTrainer``; the attributes it reads
are set by the trainer's ``__init__`` (listed in the class body).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from grid_maps import training_maps, validation_maps
from multi_agent_env import NUM_ACTIONS, MultiAgentEnv, VectorMultiAgentEnv
from n_step import NStepWindow
from paired_networks import PairedQNetworks
from rollout import EVAL_SEED, PolicyFn
from train_config import TrainConfig


@dataclass
class Rollout:
    """N environment copies being played, and what the learner tracks for each."""

    env: VectorMultiAgentEnv
    obs: np.ndarray  # (N, 2, D) current observations of A and B
    prev_obs: np.ndarray  # (N, 2, D) observations one step earlier (zeros at an episode start)
    has_prev: np.ndarray  # (N,) float32, 1.0 where prev_obs is real
    returns: np.ndarray  # (N,) return of the running episodes
    window: NStepWindow  # the steps whose n-step transitions are not complete yet

    @classmethod
    def start(cls, env: VectorMultiAgentEnv, n_step: int = 1, gamma: float = 0.99) -> Rollout:
        obs = env.reset()
        n = env.n_envs
        zeros = np.zeros(n, np.float32)
        return cls(env, obs, np.zeros_like(obs), zeros, np.zeros(n), NStepWindow(n_step, gamma, n))

    def advance(
        self, next_obs: np.ndarray, rewards: np.ndarray, finished: np.ndarray
    ) -> np.ndarray:
        """Move on to ``next_obs``; return the returns of the episodes that ``finished``."""
        self.returns += rewards
        finished_returns = self.returns[finished].copy()
        self.returns[finished] = 0.0
        self.prev_obs = np.where(finished[:, None, None], 0.0, self.obs).astype(
            np.float32, copy=False
        )
        self.has_prev = (~finished).astype(np.float32)
        self.obs = next_obs
        return finished_returns


class TrainerActing:
    """Acting with the online networks of both agents (a base class of the trainer)."""

    # Set by MultiAgentTrainer.__init__:
    cfg: TrainConfig
    env: MultiAgentEnv  # the map, window and time limit trained on
    online: PairedQNetworks
    mask: torch.Tensor  # (D,) the ablation mode's observation mask
    rng: np.random.Generator  # exploration
    noise_rng: torch.Generator  # DIAL noise on the message logits

    def make_vector_env(
        self, n_envs: int, seed: int | None, validation: bool = False
    ) -> VectorMultiAgentEnv:
        """``n_envs`` copies of the training map with the reward the trainer learns from;
        with ``map_pool`` > 0, copies that draw from the training maps (tracking the cells
        seen, for the coverage bonus) or, for ``validation``, from the validation maps."""
        cfg, size = self.cfg, self.env.grid_size
        maps = {}
        if cfg.map_pool > 0:
            pool = validation_maps(cfg.validation_maps, size) if validation else None
            maps = dict(map_pool=training_maps(cfg.map_pool, size) if pool is None else pool)
            maps["track_coverage"] = not validation and cfg.coverage_bonus > 0
        return VectorMultiAgentEnv(
            n_envs,
            grid=None if maps else self.env.grid,
            obs_window=self.env.obs_window,
            max_steps=self.env.max_steps,
            seed=seed,
            reward_mode=cfg.reward_mode,
            **maps,
        )

    def start_rollout(self, n_envs: int, seed: int | None) -> Rollout:
        return Rollout.start(self.make_vector_env(n_envs, seed), self.cfg.n_step, self.cfg.gamma)

    @property
    def network_A(self) -> torch.nn.Module:
        """Agent A's network as a standalone AgentDQN / DuelingDQN (a snapshot)."""
        return self.online.agent(0)

    @property
    def network_B(self) -> torch.nn.Module:
        return self.online.agent(1)

    def act(
        self, obs: np.ndarray, epsilon: float, rng: np.random.Generator, noisy_messages: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """obs (N, 2, D) -> ε-greedy actions (N, 2) int64 and messages (N, 2) float32."""
        with torch.inference_mode():  # = no_grad, and cheaper per operation
            q_values, logits = self.online(torch.from_numpy(obs).transpose(0, 1) * self.mask)
            logits = logits[..., 0]  # (2, N)
            if noisy_messages and self.cfg.comm_noise > 0:
                noise = torch.randn(logits.shape, generator=self.noise_rng)
                logits = noise.mul_(self.cfg.comm_noise).add_(logits)
            messages = torch.sigmoid(logits).T.numpy()
        # The first best action, as torch.max would pick it (NumPy: fewer operations).
        actions = q_values.numpy().argmax(axis=-1).T
        if epsilon > 0:  # a greedy policy draws nothing
            explore = rng.random(actions.shape) < epsilon
            actions = np.where(explore, rng.integers(0, NUM_ACTIONS, actions.shape), actions)
        return actions, messages

    def select_action(
        self, state: np.ndarray, network: torch.nn.Module, epsilon: float
    ) -> tuple[int, float]:
        """ε-greedy action and message of one agent: ``state`` (obs_dim,) raw observation."""
        masked = torch.as_tensor(state, dtype=torch.float32) * self.mask
        with torch.no_grad():
            q_values, comm = network(masked.unsqueeze(0))
        action = int(q_values.argmax(dim=1).item())
        if self.rng.random() < epsilon:
            action = int(self.rng.integers(NUM_ACTIONS))
        return action, float(comm.item())

    def policy(self, epsilon: float = 0.0, seed: int = EVAL_SEED) -> PolicyFn:
        """The current greedy/ε-greedy policy as a function for :func:`rollout.run_episodes`."""
        rng = np.random.default_rng(seed)
        return lambda obs, positions: self.act(obs, epsilon, rng, noisy_messages=False)
