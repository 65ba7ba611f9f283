"""Independent DQN for two agents that must meet on a target, with a learned message.

Each agent has its own network (a Q head over 5 moves and a sigmoid message head)
and learns from a shared replay of joint transitions with a Huber TD loss summed
over both agents, target networks, a Double-DQN target and gradient clipping.
The message is trained DIAL-style: at update time the message that arrived in the
receiver's observation is recomputed by the sender's online network from the
sender's previous observation (with noise on its logit), so the receiver's TD loss
reaches the sender's message head. The ablation modes only differ in the input
mask (:func:`apply_observation_mask`), used wherever a network sees an observation.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from models import MESSAGE_INDEX, observation_mask
from multi_agent_env import NUM_ACTIONS, MultiAgentEnv, VectorMultiAgentEnv
from paired_networks import PairedQNetworks
from replay_buffer import PrioritizedReplayBuffer, ReplayBuffer
from rollout import EVAL_EPSILON, EVAL_SEED, VALIDATION_SEED, PolicyFn, evaluate_policy
from train_config import TrainConfig

_TORCH_MASKS: dict[str, torch.Tensor] = {}


def apply_observation_mask(obs: np.ndarray | torch.Tensor, mode: str) -> np.ndarray | torch.Tensor:
    """Zero the inputs that ablation ``mode`` hides: ``independent`` elements 9 and 10
    (message, distance), ``comm`` element 10, ``full`` none. Any leading shape (..., 11)."""
    if isinstance(obs, torch.Tensor):
        if mode not in _TORCH_MASKS:
            _TORCH_MASKS[mode] = torch.tensor(observation_mask(mode))
        return obs * _TORCH_MASKS[mode]
    return np.asarray(obs, dtype=np.float32) * observation_mask(mode)


@dataclass
class Rollout:
    """A vectorised environment and what the collector tracks per copy (N copies)."""

    env: VectorMultiAgentEnv
    obs: np.ndarray  # (N, 2, D) current observations of A and B
    prev_obs: np.ndarray  # (N, 2, D) observations one step earlier (zeros at an episode start)
    has_prev: np.ndarray  # (N,) bool, whether prev_obs is real
    returns: np.ndarray  # (N,) return of the running episodes

    @classmethod
    def start(cls, env: VectorMultiAgentEnv) -> Rollout:
        obs = env.reset()
        n = env.n_envs
        return cls(env, obs, np.zeros_like(obs), np.zeros(n, dtype=bool), np.zeros(n))


class MultiAgentTrainer:
    """Trains agents A and B of one ablation mode with one seed.

    Args:
        env: the environment whose map, window and time limit training uses.
        args: a :class:`TrainConfig` (or any namespace with its fields); ``mode`` must be
            one of independent, comm, full; the run's seed is ``args.seed``.
    """

    def __init__(self, env: MultiAgentEnv, args: Any) -> None:
        known = {f.name for f in fields(TrainConfig)}
        cfg = (
            args
            if isinstance(args, TrainConfig)
            else TrainConfig(**{k: v for k, v in vars(args).items() if k in known})
        )
        self.cfg = cfg.validate()
        if cfg.mode not in ("independent", "comm", "full"):
            raise ValueError(f"a trainer trains one mode, got mode={cfg.mode!r}")
        self.mode, self.seed, self.env = cfg.mode, cfg.seed, env
        # Seeding: the networks' initial weights, message noise, exploration, replay
        # sampling and start positions all derive from the one run seed.
        torch.manual_seed(self.seed)
        self.rng = np.random.default_rng(self.seed)
        self.noise_rng = torch.Generator().manual_seed(self.seed)

        def make_env(n_envs: int, seed: int | None) -> VectorMultiAgentEnv:
            return VectorMultiAgentEnv(
                n_envs,
                grid=env.grid,
                obs_window=env.obs_window,
                max_steps=env.max_steps,
                seed=seed,
                reward_mode=cfg.reward_mode,
            )

        self._make_env = make_env
        self.rollout = Rollout.start(make_env(cfg.num_envs, self.seed))
        self._episode_rollout: Rollout | None = None  # for train_episode()
        self.obs_dim = self.rollout.env.obs_dim
        self.online = PairedQNetworks(self.obs_dim, cfg.hidden_dim, NUM_ACTIONS, cfg.dueling)
        self.target = copy.deepcopy(self.online).requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.online.parameters(), lr=cfg.lr)
        buffer_class = PrioritizedReplayBuffer if cfg.prioritized else ReplayBuffer
        self.buffer = buffer_class(cfg.buffer_size, seed=self.seed)
        self.dial = cfg.comm_learning == "dial" and self.mode != "independent"
        self.env_steps = self.episodes = self.updates = 0
        self._update_credit = 0.0
        self.recent_returns: deque[float] = deque(maxlen=100)
        self.recent_successes: deque[bool] = deque(maxlen=100)
        self.log: list[dict[str, Any]] = []
        self._losses: list[float] = []
        self.best_score, self.best_env_steps = -1.0, 0
        self._best_weights = self.online.flat.detach().clone()
        self._mean_qs: list[float] = []

    # ------------------------------------------------------------------ networks
    @property
    def network_A(self) -> torch.nn.Module:
        """Agent A's network as a standalone AgentDQN / DuelingDQN (a snapshot)."""
        return self.online.agent(0)

    @property
    def network_B(self) -> torch.nn.Module:
        return self.online.agent(1)

    def _masked(self, obs: torch.Tensor) -> torch.Tensor:
        return apply_observation_mask(obs, self.mode)

    def _act(
        self, obs: np.ndarray, epsilon: float, rng: np.random.Generator, noisy_messages: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """obs (N, 2, D) -> ε-greedy actions (N, 2) int64 and messages (N, 2) float32."""
        with torch.no_grad():
            q_values, logits = self.online(self._masked(torch.from_numpy(obs).transpose(0, 1)))
            if noisy_messages and self.cfg.comm_noise > 0:
                logits = logits + self.cfg.comm_noise * torch.randn(
                    logits.shape, generator=self.noise_rng
                )
        actions = q_values.argmax(dim=-1).T.numpy()
        explore = rng.random(actions.shape) < epsilon
        actions = np.where(explore, rng.integers(0, NUM_ACTIONS, actions.shape), actions)
        return actions, torch.sigmoid(logits[..., 0]).T.numpy()

    def select_action(
        self, state: np.ndarray, network: torch.nn.Module, epsilon: float
    ) -> tuple[int, float]:
        """ε-greedy action and message of one agent: ``state`` (11,) raw observation."""
        masked = apply_observation_mask(torch.as_tensor(state, dtype=torch.float32), self.mode)
        with torch.no_grad():
            q_values, comm = network(masked.unsqueeze(0))
        action = int(q_values.argmax(dim=1).item())
        if self.rng.random() < epsilon:
            action = int(self.rng.integers(NUM_ACTIONS))
        return action, float(comm.item())

    def policy(self, epsilon: float = 0.0, seed: int = EVAL_SEED) -> PolicyFn:
        """The current greedy/ε-greedy policy as a function for :func:`rollout.run_episodes`."""
        rng = np.random.default_rng(seed)
        return lambda obs, positions: self._act(obs, epsilon, rng, noisy_messages=False)

    # ------------------------------------------------------------------ experience
    def _progress(self) -> float:
        """Fraction of the training budget spent, in [0, 1]."""
        cfg = self.cfg
        spent = (
            self.episodes / cfg.num_episodes
            if cfg.num_episodes > 0
            else (self.env_steps / cfg.total_steps)
        )
        return min(1.0, spent)

    def epsilon(self) -> float:
        """With epsilon_decay > 0 (the skeleton's factor): epsilon_start * decay^episodes,
        floored at epsilon_end; else linear from epsilon_start to epsilon_end over the first
        epsilon_fraction of the run."""
        cfg = self.cfg
        if cfg.epsilon_decay > 0:
            return max(cfg.epsilon_end, cfg.epsilon_start * cfg.epsilon_decay**self.episodes)
        fraction = min(1.0, self._progress() / cfg.epsilon_fraction)
        return cfg.epsilon_start + fraction * (cfg.epsilon_end - cfg.epsilon_start)

    def learning_rate(self) -> float:
        """Linear from lr to lr * lr_end_factor over the run."""
        factor = 1.0 + self._progress() * (self.cfg.lr_end_factor - 1.0)
        return self.cfg.lr * factor

    def _collect_step(self, rollout: Rollout) -> tuple[np.ndarray, np.ndarray]:
        """One step of every copy; store the transitions. Returns (returns, successes) of
        the episodes that finished."""
        actions, messages = self._act(rollout.obs, self.epsilon(), self.rng, noisy_messages=True)
        next_obs, rewards, terminated, truncated, info = rollout.env.step(actions, messages)
        final_obs = info["final_obs"]
        # Only "both on target" ends an episode for learning; the time limit is a cut-off.
        self.buffer.push_batch(
            state_A=rollout.obs[:, 0],
            state_B=rollout.obs[:, 1],
            action_A=actions[:, 0],
            action_B=actions[:, 1],
            comm_A=messages[:, 0],
            comm_B=messages[:, 1],
            reward=rewards,
            next_state_A=final_obs[:, 0],
            next_state_B=final_obs[:, 1],
            done=terminated,
            prev_state_A=rollout.prev_obs[:, 0],
            prev_state_B=rollout.prev_obs[:, 1],
            has_prev=rollout.has_prev,
        )
        finished = terminated | truncated
        rollout.returns += rewards
        outcome = rollout.returns[finished].copy(), terminated[finished].copy()
        rollout.returns[finished] = 0.0
        rollout.prev_obs = np.where(finished[:, None, None], 0.0, rollout.obs).astype(np.float32)
        rollout.has_prev = ~finished
        rollout.obs = next_obs
        self.env_steps += rollout.env.n_envs
        self.episodes += int(finished.sum())
        self.recent_returns.extend(outcome[0].tolist())
        self.recent_successes.extend(outcome[1].tolist())
        self._learn(rollout.env.n_envs)
        return outcome

    def _learn(self, new_env_steps: int) -> None:
        """Run updates at the configured ratio of updates_per_step per num_envs env steps."""
        if self.env_steps < self.cfg.learning_starts:
            return
        self._update_credit += new_env_steps * self.cfg.updates_per_step / self.cfg.num_envs
        while self._update_credit >= 1.0:
            self._update_credit -= 1.0
            self._losses.append(self.update_networks(self.cfg.batch_size))

    # ------------------------------------------------------------------ learning
    def update_networks(self, batch_size: int) -> float:
        """One gradient step on a sampled batch; returns the loss (sum over both agents)."""
        batch, weights, indices = self.buffer.sample_batch(batch_size)
        per_agent, td_errors, q_taken = self.td_losses(batch, weights)
        loss = per_agent.sum()  # the assignment's L = L_A + L_B
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.online.parameters(), self.cfg.max_grad_norm)
        self.optimizer.step()
        self.updates += 1
        if self.updates % self.cfg.target_update == 0:
            self.target.load_state_dict(self.online.state_dict())
        if self.cfg.prioritized:  # one priority per joint transition: the larger TD error
            self.buffer.update_priorities(indices, td_errors.max(dim=0).values.numpy() + 1e-6)
        self._mean_qs.append(float(q_taken.mean()))
        return float(loss.detach())

    def td_losses(
        self, batch: dict[str, np.ndarray], weights: np.ndarray
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Huber TD losses of a batch of B joint transitions.

        Returns (loss per agent [2] with gradient, |TD error| [2, B], Q(s, a) [2, B]), the
        latter two detached. ``weights`` [B] are importance weights (ones without PER).
        """
        t = {name: torch.from_numpy(value) for name, value in batch.items()}
        obs = torch.stack([t["state_A"], t["state_B"]])  # (2, B, D)
        next_obs = torch.stack([t["next_state_A"], t["next_state_B"]])
        actions = torch.stack([t["action_A"], t["action_B"]]).unsqueeze(-1)  # (2, B, 1)
        reward, not_done = t["reward"], 1.0 - t["done"]  # (B,)

        online, target_weights = self.online.weights(), self.target.weights()
        if self.dial:
            obs, next_obs = self._splice_messages(obs, next_obs, t, online, target_weights)
        with torch.no_grad():
            next_q_online, _ = self.online(self._masked(next_obs), online)
            best_next = next_q_online.argmax(dim=-1, keepdim=True)  # Double DQN
            next_q_target, _ = self.target(self._masked(next_obs), target_weights)
            next_value = next_q_target.gather(-1, best_next)[..., 0]
            target = reward + self.cfg.gamma * not_done * next_value
        q_values, _ = self.online(self._masked(obs), online)
        q_taken = q_values.gather(-1, actions)[..., 0]  # (2, B)
        per_sample = F.smooth_l1_loss(q_taken, target, reduction="none")
        per_agent = (per_sample * torch.from_numpy(weights)).mean(dim=1)
        return per_agent, (q_taken - target).abs().detach(), q_taken.detach()

    def _splice_messages(
        self,
        obs: torch.Tensor,
        next_obs: torch.Tensor,
        t: dict[str, torch.Tensor],
        online: tuple[torch.Tensor, ...],
        target: tuple[torch.Tensor, ...],
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """DIAL: replace the stored incoming messages (element 9) by recomputed ones.

        At time t agent A received the message B sent at t-1, computed from B's
        observation at t-1 (``prev_state_B``). Recomputing it with B's online network,
        with gradient and with noise on the logit, lets A's TD loss train B's message
        head (and vice versa). The message in the next observation (sent at t from the
        stored observations) comes from the partner's target network, without gradient.
        """
        prev_obs = torch.stack([t["prev_state_A"], t["prev_state_B"]])
        _, logits = self.online(self._masked(prev_obs), online)
        if self.cfg.comm_noise > 0:
            logits = logits + self.cfg.comm_noise * torch.randn(
                logits.shape, generator=self.noise_rng
            )
        received = torch.sigmoid(logits).flip(0) * t["has_prev"].float()[None, :, None]
        with torch.no_grad():
            _, next_logits = self.target(self._masked(obs), target)
            next_received = torch.sigmoid(next_logits).flip(0)
        splice = MESSAGE_INDEX

        def with_message(x: torch.Tensor, message: torch.Tensor) -> torch.Tensor:
            return torch.cat([x[..., :splice], message, x[..., splice + 1 :]], dim=-1)

        return with_message(obs, received), with_message(next_obs, next_received)

    # ------------------------------------------------------------------ loops
    def train_episode(self) -> tuple[float, bool]:
        """Play one episode in a single environment (learning as it goes);
        returns (episode_reward, success)."""
        if self._episode_rollout is None:
            self._episode_rollout = Rollout.start(self._make_env(1, self.seed + 1))
        while True:
            returns, successes = self._collect_step(self._episode_rollout)
            if len(returns):
                return float(returns[0]), bool(successes[0])

    def evaluate(
        self, num_episodes: int = 10, epsilon: float = 0.0, seed: int = EVAL_SEED
    ) -> tuple[float, float]:
        """(mean reward, success rate) over fixed episodes (the test episodes by default)."""
        env = self._make_env(min(num_episodes, 500), None)
        summary = evaluate_policy(env, self.policy(epsilon), num_episodes, seed=seed)
        return summary["mean_return"], summary["success_rate"]

    def _done(self) -> bool:
        cfg = self.cfg
        if cfg.num_episodes > 0:
            return self.episodes >= cfg.num_episodes
        return self.env_steps >= cfg.total_steps

    def _log_row(self) -> dict[str, Any]:
        """Evaluate on the validation episodes, remember the best weights, log a row."""
        episodes = self.cfg.eval_episodes
        greedy_return, greedy_success = self.evaluate(episodes, 0.0, VALIDATION_SEED)
        eps_return, eps_success = self.evaluate(episodes, EVAL_EPSILON, VALIDATION_SEED)
        score = (greedy_success + eps_success) / 2
        if score > self.best_score:
            self.best_score, self.best_env_steps = score, self.env_steps
            self._best_weights = self.online.flat.detach().clone()
        row = {
            "env_steps": self.env_steps,
            "episodes": self.episodes,
            "updates": self.updates,
            "epsilon": round(self.epsilon(), 6),
            "loss": float(np.mean(self._losses)) if self._losses else math.nan,
            "mean_q": float(np.mean(self._mean_qs)) if self._mean_qs else math.nan,
            "train_return": float(np.mean(self.recent_returns))
            if self.recent_returns
            else math.nan,
            "train_success": float(np.mean(self.recent_successes))
            if self.recent_successes
            else math.nan,
            "eval_success_greedy": greedy_success,
            "eval_success_eps": eps_success,
            "eval_return_greedy": greedy_return,
            "eval_return_eps": eps_return,
        }
        self._losses, self._mean_qs = [], []
        self.log.append(row)
        return row

    def train(self, progress: Callable[[dict[str, Any]], None] | None = None) -> list[dict]:
        """Collect with the vectorised environments and learn until the budget is spent.
        Evaluates every ``eval_interval`` env steps; returns the log rows."""
        next_eval = 0
        while not self._done():
            if self.env_steps >= next_eval:
                row = self._log_row()
                next_eval += self.cfg.eval_interval
                if progress:
                    progress(row)
            self._collect_step(self.rollout)
        row = self._log_row()
        if progress:
            progress(row)
        if self.cfg.keep_best:
            with torch.no_grad():
                self.online.flat.copy_(self._best_weights)
        return self.log
