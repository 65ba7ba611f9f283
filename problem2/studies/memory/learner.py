"""Recurrent Q-learning (DRQN-style) for the memory agents, on the core trainer's loop.

:class:`RecurrentTrainer` keeps everything of :class:`trainer.DQNTrainer` but what
memory changes: the network (:class:`agents.RecurrentQNetwork`, one set of weights for both
agents, as in the map-pool recipe), acting with a hidden state per agent and copy, replay of
whole episodes (:class:`EpisodeReplay`) and the TD loss over sequences
(:meth:`RecurrentTrainer.td_loss`). The loop (act → step → store → update → target sync →
schedules → evaluate and log), the reward shaping, the schedules and checkpoint selection
are the core's own methods.

Sizes: a batch of ``batch_size // 16`` stored episodes (16 for 256), a buffer of
``buffer_size // max_steps`` episodes (2000 for 100 000 and 50 steps).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_SEED
from torch.nn import functional as F

from studies.memory.agents import NUM_ACTIONS, RecurrentQNetwork, export_recurrent, memory_policy
from studies.pool_training import CurriculumEnv, PoolConfig, PoolTrainer

TRANSITIONS_PER_EPISODE = 16  # a batch of batch_size transitions: batch_size // 16 episodes
CURRICULUM_END = 0.5  # fraction of the run at which the curriculum's share reaches 0


@dataclass(frozen=True)
class Levers:
    """Additions meant to make a receiver use the message (all off by default)."""

    distance_potential: float = 0.0
    """c of the shaping term c (d − γ d'), d the agents' distance (learning only)."""
    listening: float = 0.0
    """λ of the positive-listening loss −λ E‖softmax Q(message) − softmax Q(mean message)‖₁."""
    signalling: float = 0.0
    """λ of the positive-signalling loss: −λ (H(mean message) − mean H(message))."""
    curriculum: float = 0.0
    """share of new training episodes that start with one agent on the target, falling
    linearly to 0 at ``CURRICULUM_END`` of the run (homing is learned before search)."""

    def __post_init__(self) -> None:
        for name in ("distance_potential", "listening", "signalling", "curriculum"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0.0 <= value < math.inf):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if self.curriculum > 1:
            raise ValueError(f"curriculum must be a share in [0, 1], got {self.curriculum!r}")


def binary_entropy(p: torch.Tensor) -> torch.Tensor:
    p = p.clamp(1e-6, 1 - 1e-6)
    return -(p * p.log() + (1 - p) * (1 - p).log())


class EpisodeReplay:
    """Whole joint episodes, padded to T = max_steps: ``obs`` (C, T + 1, 2, D) before each
    step and after the last, ``actions`` (C, T, 2) int64 (−1 after the end), ``rewards``
    (C, T) the learning reward (0 after the end), ``lengths`` (C,), ``terminated`` (C,)
    (both agents on the target; otherwise cut off at T). Oldest episodes are overwritten."""

    def __init__(self, capacity: int, max_steps: int, obs_dim: int, seed: int) -> None:
        self.capacity, self.max_steps = capacity, max_steps
        self.obs = np.zeros((capacity, max_steps + 1, 2, obs_dim), np.float32)
        self.actions = np.full((capacity, max_steps, 2), -1, np.int64)
        self.rewards = np.zeros((capacity, max_steps), np.float32)
        self.lengths = np.zeros(capacity, np.int64)
        self.terminated = np.zeros(capacity, bool)
        self.size = self.next = 0
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return self.size

    def push(
        self,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        lengths: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """K finished episodes in the padded layout above (each field (K, ...))."""
        slots = (self.next + np.arange(len(lengths))) % self.capacity
        self.obs[slots], self.actions[slots], self.rewards[slots] = obs, actions, rewards
        self.lengths[slots], self.terminated[slots] = lengths, terminated
        self.next = int((self.next + len(lengths)) % self.capacity)
        self.size = min(self.capacity, self.size + len(lengths))

    def sample(self, episodes: int) -> dict[str, torch.Tensor]:
        """``episodes`` stored episodes drawn uniformly with replacement, as tensors."""
        rows = self.rng.integers(self.size, size=episodes)
        return {
            "obs": torch.from_numpy(self.obs[rows]),
            "actions": torch.from_numpy(self.actions[rows]),
            "rewards": torch.from_numpy(self.rewards[rows]),
            "lengths": torch.from_numpy(self.lengths[rows]),
            "terminated": torch.from_numpy(self.terminated[rows]),
        }


class RecurrentTrainer(PoolTrainer):
    """Trains two agents with memory (shared weights) in one of ``agents.MEMORY_MODES``.

    Args:
        env: the environment whose grid size, window and time limit training uses.
        cfg: a validated :class:`PoolConfig` (its ``mode`` is ignored: ``mode`` is used).
        mode: independent, comm, distance or full.
        levers: the listening levers (:class:`Levers`), none by default.
    """

    def __init__(
        self, env: MultiAgentEnv, cfg: PoolConfig, mode: str, levers: Levers = Levers()
    ) -> None:
        if cfg.target_potential > 0 and cfg.potential_credit == "agent":  # not in this td_loss
            raise ValueError(
                "potential_credit must be team for memory agents with target_potential > 0 "
                "(their td_loss adds no per-agent arrival term), got agent"
            )
        self.cfg, self.env, self.mode, self.seed = cfg, env, mode, cfg.seed
        self.levers = levers
        if levers.curriculum > 0:
            self.vector_env_class = CurriculumEnv
        self.name = f"{mode}_seed{cfg.seed}"
        output_dir = Path(cfg.output_dir)
        self.models_dir, self.logs_dir = output_dir / "agent_models", output_dir / "training_logs"
        torch.manual_seed(self.seed)
        self.rng = np.random.default_rng(self.seed)
        self.noise_rng = torch.Generator().manual_seed(self.seed)

        self.rollout = self.start_rollout(cfg.num_envs, self.seed)
        self.obs_dim = self.rollout.env.obs_dim
        self.online = RecurrentQNetwork(mode, cfg.hidden_dim, self.obs_dim)
        self.target = RecurrentQNetwork(mode, cfg.hidden_dim, self.obs_dim)
        self.target.load_state_dict(self.online.state_dict())
        self.target.requires_grad_(False)
        self.online_parameters = list(self.online.parameters())
        self.target_parameters = list(self.target.parameters())
        self.optimizer = torch.optim.Adam(self.online_parameters, lr=cfg.lr)
        capacity = max(1, cfg.buffer_size // env.max_steps)
        self.replay_buffer = EpisodeReplay(capacity, env.max_steps, self.obs_dim, self.seed)
        self.batch_episodes = max(1, cfg.batch_size // TRANSITIONS_PER_EPISODE)
        self.dial = cfg.comm_learning == "dial" and mode in ("comm", "full")
        self.epsilon = cfg.epsilon_start
        self.env_steps = self.episodes = self.updates = 0
        self.recent_returns: deque[float] = deque(maxlen=100)
        self.recent_successes: deque[bool] = deque(maxlen=100)
        self.log: list[dict[str, Any]] = []
        self._losses: list[float] = []
        self._mean_qs: list[float] = []
        self.checkpoints = []
        self._evaluation_envs = {}
        # Acting state of the training copies, and the episodes they are playing.
        n, horizon = cfg.num_envs, env.max_steps
        self._hidden = self.online.initial_state(2 * n)  # rows: A of every copy, then B
        self._previous = np.full((n, 2), -1, np.int64)
        self._running = EpisodeReplay(n, horizon, self.obs_dim, self.seed)
        self._running.size = n
        self._t = np.zeros(n, np.int64)

    # ------------------------------------------------------------------ 1. act
    def act(
        self, obs: np.ndarray, epsilon: float, rng: np.random.Generator, noisy_messages: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """ε-greedy actions (N, 2) and messages (N, 2) of the training copies; a copy's
        hidden state and previous action start afresh where its episode starts."""
        n = len(obs)
        starting = self.rollout.env.steps == 0
        self._previous[starting] = -1
        restart = torch.from_numpy(np.concatenate([starting, starting]))[:, None]
        stacked = torch.from_numpy(np.ascontiguousarray(obs.transpose(1, 0, 2))).reshape(2 * n, -1)
        previous = torch.from_numpy(self._previous.T.reshape(-1).copy())
        with torch.inference_mode():
            hidden = torch.where(restart, 0.0, self._hidden)
            q_values, logits, self._hidden = self.online.step(stacked, previous, hidden)
            if noisy_messages and self.dial and self.cfg.comm_noise > 0:
                logits = logits + self.cfg.comm_noise * torch.randn(
                    logits.shape, generator=self.noise_rng
                )
            messages = torch.sigmoid(logits).reshape(2, n).T.numpy()
        actions = q_values.numpy().argmax(axis=-1).reshape(2, n).T
        if epsilon > 0:
            explore = rng.random(actions.shape) < epsilon
            actions = np.where(explore, rng.integers(0, NUM_ACTIONS, actions.shape), actions)
        self._previous = actions.astype(np.int64)
        return actions, messages

    def collect(self, rollout: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The core's collect, after setting the curriculum's share (``Levers.curriculum``)
        for the episodes that start in it."""
        if self.levers.curriculum > 0:
            remaining = max(0.0, 1.0 - self.progress() / CURRICULUM_END)
            rollout.env.start_on_target = self.levers.curriculum * remaining
        return super().collect(rollout)

    def learning_rewards(
        self, rewards: np.ndarray, info: dict[str, np.ndarray], obs: np.ndarray
    ) -> np.ndarray:
        """The core's learning rewards, plus c (d − γ d') with d the agents' distance before
        the step and d' after it (``Levers.distance_potential``: the potential −c d)."""
        rewards = super().learning_rewards(rewards, info, obs)
        c = self.levers.distance_potential
        if c > 0:
            index = self.obs_dim - 1
            before, after = obs[:, 0, index], info["final_obs"][:, 0, index]
            rewards = rewards + c * (before - self.cfg.gamma * after)
        return rewards

    # ------------------------------------------------------------------ 3. store
    def store(
        self,
        rollout: Any,
        actions: np.ndarray,
        messages: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> None:
        """Write this step into the running episodes; push those that ended, whole."""
        running, copies, t = self._running, np.arange(len(actions)), self._t
        running.obs[copies, t], running.actions[copies, t] = rollout.obs, actions
        running.rewards[copies, t] = rewards
        t += 1
        running.obs[copies, t] = next_obs
        finished = np.flatnonzero(terminated | truncated)
        if len(finished):
            self.replay_buffer.push(
                running.obs[finished],
                running.actions[finished],
                running.rewards[finished],
                t[finished],
                terminated[finished],
            )
            running.actions[finished], running.rewards[finished] = -1, 0.0
            t[finished] = 0

    # ------------------------------------------------------------------ 4. update
    def td_loss(
        self, batch: dict[str, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The Huber TD loss over E stored episodes of both agents (2E sequences).

        Each sequence is unrolled from a zero state; at its step t < L (its length) the
        target is the n-step Double-DQN target y_t = Σ_{j<k} γ^j r_{t+j} + γ^k Q⁻(s_{t+k},
        argmax_a Q(s_{t+k}, a)), k = min(n, L − t), without the last term where k reaches
        a terminal step. With DIAL the partner's message received at t ≥ 1 is recomputed
        by the online network (noise on the logit) from the partner's own sequence, so the
        receiver's loss trains the sender. Returns (loss, TD errors, Q(s, a)) over valid steps."""
        cfg = self.cfg
        obs = batch["obs"].permute(1, 2, 0, 3).reshape(-1, 2 * len(batch["lengths"]), self.obs_dim)
        actions = batch["actions"].permute(1, 2, 0).reshape(obs.shape[0] - 1, -1)  # (T, 2E)
        horizon = actions.shape[0]
        previous = torch.cat([torch.full_like(actions[:1], -1), actions], 0)  # (T + 1, 2E)
        lengths = batch["lengths"].repeat(2)
        terminated = batch["terminated"].repeat(2)
        levers, index = self.levers, self.obs_dim - 2  # index: the received message
        valid = torch.arange(horizon + 1)[:, None] < lengths[None, :]  # (T + 1, 2E)
        extra = torch.zeros(())
        if self.dial:
            _, logits, _ = self.online.unroll(obs, previous)
            if levers.signalling > 0:  # sent messages that differ between states
                sent_p = torch.sigmoid(logits)[valid]
                spread = binary_entropy(sent_p.mean()) - binary_entropy(sent_p).mean()
                extra = extra - levers.signalling * spread
            if cfg.comm_noise > 0:
                logits = logits + cfg.comm_noise * torch.randn(
                    logits.shape, generator=self.noise_rng
                )
            sent = torch.sigmoid(logits).roll(obs.shape[1] // 2, dims=1)  # the partner's
            received = torch.cat([obs[:1, :, index], sent[:-1]], 0)
            obs = torch.cat([obs[..., :index], received.unsqueeze(-1), obs[..., index + 1 :]], -1)
        q_online, _, _ = self.online.unroll(obs, previous)  # (T + 1, 2E, 5)
        if levers.listening > 0 and self.mode in ("comm", "full"):  # act on what is heard
            mean_message = obs[..., index][valid].mean().detach()
            plain = torch.cat(
                [
                    obs[..., :index],
                    torch.full_like(obs[..., index : index + 1], float(mean_message)),
                    obs[..., index + 1 :],
                ],
                -1,
            )
            q_plain, _, _ = self.online.unroll(plain, previous)
            change = (q_online.softmax(-1) - q_plain.softmax(-1)).abs().sum(-1)[valid]
            extra = extra - levers.listening * change.mean()
        with torch.no_grad():
            q_target, _, _ = self.target.unroll(obs, previous)
            best = q_online.argmax(dim=-1, keepdim=True)
            value = q_target.gather(-1, best)[..., 0]  # (T + 1, 2E)
            steps = torch.arange(horizon)[:, None]
            k = (lengths[None, :] - steps).clamp(min=0, max=cfg.n_step)  # (T, 2E)
            rewards = batch["rewards"].T.repeat(1, 2)  # (T, 2E), team reward for both
            padded = torch.cat([rewards, torch.zeros(cfg.n_step, rewards.shape[1])], 0)
            returns = sum(
                cfg.gamma**j * padded[j : j + horizon] * (j < k) for j in range(cfg.n_step)
            )
            reach = steps + k
            ends = terminated[None, :] & (reach == lengths[None, :])
            discount = torch.where(ends, 0.0, cfg.gamma ** k.float())
            target = returns + discount * value.gather(0, reach)
        valid = valid[:horizon]
        taken = actions.clamp(min=0).unsqueeze(-1)
        q_taken = q_online[:horizon].gather(-1, taken)[..., 0]
        per_step = F.smooth_l1_loss(q_taken, target, reduction="none")
        half = obs.shape[1] // 2
        counts = valid.float().sum()
        # Summed over both agents (L_A + L_B), each the mean over its valid steps.
        loss = sum((per_step * valid)[:, i * half : (i + 1) * half].sum() for i in range(2))
        loss = 2 * loss / counts
        if levers.listening > 0 or levers.signalling > 0:
            loss = loss + extra
        return loss, (q_taken - target).detach()[valid], q_taken.detach()[valid]

    def update_networks(self, batch_size: int) -> float:
        """One gradient step on ``batch_episodes`` stored episodes (0.0 while fewer), then
        the core's target sync."""
        if len(self.replay_buffer) < self.batch_episodes:
            return 0.0
        loss, _, q_taken = self.td_loss(self.replay_buffer.sample(self.batch_episodes))
        self.optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.online_parameters, self.cfg.max_grad_norm)
        self.optimizer.step()
        self.updates += 1
        self.sync_target()
        loss_value = float(loss.detach())
        self._losses.append(loss_value)
        self._mean_qs.append(float(q_taken.mean()))
        return loss_value

    # ------------------------------------------------------------------ 7. evaluate, save
    def evaluation_policy(self, env: Any, epsilon: float) -> Any:
        """Both agents' memory policy in ``env`` (the core's evaluations play it)."""
        return memory_policy((self.online, self.online), env, epsilon, EVAL_SEED)

    def policy(self, epsilon: float = 0.0, seed: int = EVAL_SEED) -> Any:
        raise TypeError(
            "a memory agent's policy needs its environment: use evaluation_policy(env, eps)"
        )

    def export_agent(self, index: int, path: Path) -> Path:
        """Write agent ``index`` by the memory contract (both agents share the weights)."""
        return export_recurrent(self.online, path)
