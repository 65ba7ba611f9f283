"""Independent DQN for two agents that must meet on a target, with a learned message.

Each agent has its own network (a Q head over 5 moves and a sigmoid message head)
and learns from a shared replay of joint transitions with a Huber TD loss summed
over both agents, target networks, a Double-DQN target and gradient clipping.
The message is trained DIAL-style: at update time the message that arrived in the
receiver's observation is recomputed by the sender's online network from the
sender's previous observation (with noise on its logit), so the receiver's TD loss
reaches the sender's message head. The ablation modes only differ in the input
mask (:func:`apply_observation_mask`), used wherever a network sees an observation.

:meth:`MultiAgentTrainer.train` is the algorithm, step by step; :meth:`td_loss` is the
loss. For the plain network the update computes the gradient of that loss by hand
(:mod:`td_update`, several times faster on a CPU, held equal to autograd by a test).
Acting is in :mod:`trainer_acting`, the evaluations and outputs in :mod:`trainer_outputs`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from models import observation_mask
from multi_agent_env import NUM_ACTIONS, MultiAgentEnv, VectorMultiAgentEnv
from paired_networks import FlatAdam, PairedQNetworks
from replay_buffer import (
    STATE_FIELDS,
    TRANSITION_FIELDS,
    PrioritizedReplayBuffer,
    ReplayBuffer,
)
from rollout import EVAL_EPSILON
from td_update import FastTDGradient, TransitionBatch
from train_config import TrainConfig
from trainer_acting import Rollout, TrainerActing
from trainer_outputs import Checkpoint, TrainerOutputs


def apply_observation_mask(obs: np.ndarray | torch.Tensor, mode: str) -> np.ndarray | torch.Tensor:
    """Zero the inputs that ablation ``mode`` hides: ``independent`` the message and the
    distance (the last two elements, 9 and 10 for a 3 x 3 window), ``comm`` the distance,
    ``full`` none. Any leading shape (..., obs_dim)."""
    mask = observation_mask(mode, obs.shape[-1])
    if isinstance(obs, torch.Tensor):
        return obs * torch.tensor(mask)
    return np.asarray(obs, dtype=np.float32) * mask


def config_from(args: Any) -> TrainConfig:
    """A TrainConfig from a TrainConfig or any namespace (e.g. the course skeleton's, whose
    ``grid_size`` is a list and whose ``mode`` may be missing or ``all``: one trainer trains
    ``full`` then; without ``output_dir`` it writes under ``results/`` of the current folder).
    Unknown attributes are ignored; the map comes from the environment."""
    if isinstance(args, TrainConfig):
        settings = args.to_dict()
    else:
        known = {f.name for f in fields(TrainConfig)}
        settings = {k: v for k, v in vars(args).items() if k in known and v is not None}
    if settings.get("mode", "all") == "all":
        settings["mode"] = "full"
    # Like the skeleton, a namespace without output_dir writes under ./results.
    settings.setdefault("output_dir", "results")
    settings.pop("grid_size", None)  # the trainer trains on env's grid
    return TrainConfig(**settings).validate()


class MultiAgentTrainer(TrainerActing, TrainerOutputs):
    """Trains agents A and B of one ablation mode with one seed.

    Here: the state of a run, learning from replay, the schedules and the training loop.
    Acting (``act``, ``policy``, ``make_vector_env``, ...) is in :mod:`trainer_acting`;
    evaluation and outputs (``evaluate``, ``evaluate_and_log``, ``save_models``, the log)
    in :mod:`trainer_outputs`.

    Args:
        env: the environment whose map, window and time limit training uses.
        args: a :class:`TrainConfig`, or any namespace with some of its fields (the course
            skeleton's works); ``mode`` one of independent, comm, full (missing or ``all``
            means full); the run's seed is ``args.seed``; outputs go to
            ``<args.output_dir>/agent_models`` and ``/training_logs`` (default ``results``).
    """

    def __init__(self, env: MultiAgentEnv, args: Any) -> None:
        cfg = self.cfg = config_from(args)
        if cfg.mode not in ("independent", "comm", "full"):
            raise ValueError(f"a trainer trains one mode, got mode={cfg.mode!r}")
        self.mode, self.seed, self.env = cfg.mode, cfg.seed, env
        self.name = f"{cfg.mode}_seed{cfg.seed}"
        output_dir = Path(cfg.output_dir)
        self.models_dir, self.logs_dir = output_dir / "agent_models", output_dir / "training_logs"
        # Seeding: the networks' initial weights, message noise, exploration, replay
        # sampling and start positions all derive from the one run seed.
        torch.manual_seed(self.seed)
        self.rng = np.random.default_rng(self.seed)
        self.noise_rng = torch.Generator().manual_seed(self.seed)

        self.rollout = self.start_rollout(cfg.num_envs, self.seed)
        self.obs_dim = self.rollout.env.obs_dim
        self.mask = torch.tensor(observation_mask(self.mode, self.obs_dim))
        self.online = PairedQNetworks(self.obs_dim, cfg.hidden_dim, NUM_ACTIONS, cfg.dueling)
        self.target = PairedQNetworks(self.obs_dim, cfg.hidden_dim, NUM_ACTIONS, cfg.dueling)
        if cfg.share_weights:  # one set of weights: B starts as a copy of A
            self.online.load_agents([self.online.agent(0)] * 2)
        self.target.load_state_dict(self.online.state_dict())
        self.target.requires_grad_(False)
        self.optimizer = FlatAdam(self.online.flat, lr=cfg.lr)  # = torch.optim.Adam, faster
        buffer_class = PrioritizedReplayBuffer if cfg.prioritized else ReplayBuffer
        self.replay_buffer = buffer_class(cfg.buffer_size, seed=self.seed)
        self.dial = cfg.comm_learning == "dial" and self.mode != "independent"
        self.fast_gradient = (
            None
            if cfg.dueling
            else FastTDGradient(
                self.online, self.target, self.mask, self.dial, cfg.comm_noise,
                self.noise_rng, weighted=cfg.prioritized,
            )
        )  # fmt: skip
        self._batches: dict[tuple, tuple[TransitionBatch, np.ndarray, torch.Tensor, dict]] = {}
        self.epsilon = cfg.epsilon_start
        self.env_steps = self.episodes = self.updates = 0
        self.last_td_errors: torch.Tensor | None = None  # (2, B) of the last update
        self.last_indices: np.ndarray | None = None  # replay slots of the last update
        self.recent_returns: deque[float] = deque(maxlen=100)
        self.recent_successes: deque[bool] = deque(maxlen=100)
        self.log: list[dict[str, Any]] = []
        self._losses: list[float] = []
        self._mean_qs: list[float] = []
        self.checkpoints: list[Checkpoint] = []  # one per periodic evaluation
        self._episode_rollout: Rollout | None = None  # for train_episode()
        self._evaluation_envs: dict[int, VectorMultiAgentEnv] = {}  # by number of copies

    # ------------------------------------------------------------------ learning
    def store(
        self, rollout: Rollout, actions: np.ndarray, messages: np.ndarray, rewards: np.ndarray,
        next_obs: np.ndarray, terminated: np.ndarray, truncated: np.ndarray,
    ) -> None:  # fmt: skip
        """Push the joint transitions that this step of the N episodes completes (N of them
        with n_step 1; see :class:`n_step.NStepWindow`); with each, the observations
        one step before its start (DIAL). ``next_obs`` is the true next observation also
        where an episode was cut off (``truncated``). Into a buffer that was first filled by
        hand (the ten fields only) it pushes this step's one-step transitions instead."""
        buffer = self.replay_buffer
        if len(buffer) and "discount" not in buffer.field_names:
            # A buffer first filled by hand holds the ten fields of one-step transitions.
            buffer.push_batch(
                state_A=rollout.obs[:, 0], state_B=rollout.obs[:, 1],
                action_A=actions[:, 0], action_B=actions[:, 1],
                comm_A=messages[:, 0], comm_B=messages[:, 1], reward=rewards,
                next_state_A=next_obs[:, 0], next_state_B=next_obs[:, 1], done=terminated,
            )  # fmt: skip
            return
        if not buffer.layout:  # an empty buffer: the columns of what the trainer stores
            buffer.allocate(self.transition_shapes())
        n = rollout.env.n_envs
        start = {  # each pair of fields side by side: A's columns, then B's
            "state_A": rollout.obs.reshape(n, -1), "prev_state_A": rollout.prev_obs.reshape(n, -1),
            "action_A": actions, "comm_A": messages, "has_prev": rollout.has_prev,
        }  # fmt: skip
        finished = terminated | truncated
        rows = rollout.window.add(
            buffer.layout, start, rewards, next_obs, rollout.obs, terminated, finished
        )
        if len(rows):  # the environment checked the actions and clipped the messages
            buffer.push_rows(rows)

    def transition_shapes(self) -> dict[str, tuple[int, ...]]:
        """The replay fields the trainer stores, with their per-transition shapes: the ten
        required, each agent's previous observation and ``has_prev`` (DIAL), ``discount``
        and, with n-step returns, the observations one step before the next
        (``last_state_*``)."""
        observation = (self.obs_dim,)
        shapes = {name: observation if name in STATE_FIELDS else () for name in TRANSITION_FIELDS}
        states = ["prev_state"] + ["last_state"] * (self.cfg.n_step > 1)
        shapes |= {f"{name}_{agent}": observation for name in states for agent in "AB"}
        return shapes | {"discount": (), "has_prev": ()}

    def sample(self, batch_size: int) -> TransitionBatch:
        """A batch from the replay buffer: its packed rows, gathered into one tensor that
        is reused from update to update and that the batch's fields view."""
        layout = self.replay_buffer.layout  # fixed once the buffer holds a transition
        key = (batch_size, id(layout), len(layout))
        if key not in self._batches:
            width = max(columns.stop for columns in layout.values())
            rows = torch.zeros(batch_size, width)
            batch = TransitionBatch.of_rows(rows, layout, self.obs_dim)
            actions = TransitionBatch.stored_actions(rows, layout)
            self._batches = {key: (batch, rows.numpy(), actions, layout)}
        batch, rows, actions, _ = self._batches[key]  # (the layout kept: its id stays its own)
        weights, self.last_indices = self.replay_buffer.sample_rows(batch_size, rows)
        batch.actions.copy_(actions)
        if "discount" not in layout:  # transitions pushed by hand: d = γ (1 − done)
            torch.mul(batch.done, -self.cfg.gamma, out=batch.discount).add_(self.cfg.gamma)
        if self.cfg.prioritized:
            batch.weights.copy_(torch.from_numpy(weights))
        return batch

    def td_loss(self, batch: TransitionBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The Huber TD loss, summed over both agents (the assignment's L = L_A + L_B).

        Returns (loss with gradient, TD errors δ (2, B), Q(s, a) (2, B)), the last two
        detached. Terminal only when both reached the target; Double-DQN target. With
        n-step returns R is the discounted reward of k <= n steps and d = γ^k (0 where
        terminal); with k = 1 that is r and γ (1 − done)."""
        obs, next_obs = batch.obs * self.mask, batch.next_obs * self.mask
        if self.dial:
            obs, next_obs = self.splice_messages(batch, obs, next_obs)
        with torch.no_grad():  # y = R + d Q_target(s', argmax_a Q_online(s', a))
            best_next = self.online(next_obs)[0].max(dim=-1, keepdim=True).indices
            next_value = self.target(next_obs)[0].gather(-1, best_next)[..., 0]
            target = batch.reward + batch.discount * next_value
        q_taken = self.online(obs)[0].gather(-1, batch.actions.unsqueeze(-1))[..., 0]
        per_sample = F.smooth_l1_loss(q_taken, target, reduction="none")  # (2, B)
        loss = (per_sample * batch.weights).mean(dim=1).sum()
        return loss, (q_taken - target).detach(), q_taken.detach()

    def splice_messages(
        self, batch: TransitionBatch, obs: torch.Tensor, next_obs: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """DIAL: replace the incoming messages (element w²) of masked ``obs`` and
        ``next_obs`` (2, B, D) by recomputed ones.

        At time t agent A received the message B sent at t-1, computed from B's
        observation at t-1 (``prev_obs[1]``). Recomputing it with B's online network,
        with gradient and with noise on the logit, lets A's TD loss train B's message
        head (and vice versa). Where no previous observation is stored (an episode start,
        or a transition pushed by hand) the stored message stays. The message in the next
        observation s' comes from the partner's target network, without gradient, on the
        partner's observation one step before s' (``last_obs``: ``obs`` itself for one-step
        transitions), as it would have been sent; with n-step returns the message that
        actually arrived was sent by an older network with exploration noise.
        """
        m = self.obs_dim - 2
        _, logits = self.online(batch.prev_obs * self.mask)
        if self.cfg.comm_noise > 0:
            noise = torch.randn(logits.shape, generator=self.noise_rng)
            logits = logits + self.cfg.comm_noise * noise
        has_prev = batch.has_prev.view(1, -1, 1) > 0
        received = torch.where(has_prev, torch.sigmoid(logits).flip(0), obs[..., m : m + 1])
        with torch.no_grad():
            last_obs = batch.last_obs * self.mask
            next_received = torch.sigmoid(self.target(last_obs)[1]).flip(0)

        def with_message(x: torch.Tensor, message: torch.Tensor) -> torch.Tensor:
            return torch.cat([x[..., :m], message, x[..., m + 1 :]], dim=-1)

        return with_message(obs, received), with_message(next_obs, next_received)

    def update_networks(self, batch_size: int) -> float:
        """One gradient step of both agents on a sampled batch; returns the loss (0.0 while
        the buffer holds fewer than ``batch_size`` transitions)."""
        if len(self.replay_buffer) < batch_size:
            return 0.0
        batch = self.sample(batch_size)
        if self.fast_gradient is not None:  # the gradient of td_loss, written by hand
            loss, self.last_td_errors, mean_q = self.fast_gradient(batch)
        else:
            self.optimizer.zero_grad()
            loss_tensor, self.last_td_errors, q_taken = self.td_loss(batch)
            loss_tensor.backward()
            loss, mean_q = float(loss_tensor.detach()), float(q_taken.mean())
        if self.cfg.share_weights:  # one shared parameter: the sum of both agents' gradients
            for gradient in self.online.gradients():  # each (2, ...), agent axis first
                gradient.copy_(gradient.sum(dim=0, keepdim=True).expand_as(gradient))
        self.optimizer.step(grad_divisor=self.online.clip_divisor(self.cfg.max_grad_norm))
        self.updates += 1
        self._losses.append(loss)
        self._mean_qs.append(mean_q)
        return loss

    def learning_rewards(self, rewards: np.ndarray, info: dict[str, np.ndarray]) -> np.ndarray:
        """The team rewards (N,) plus the optional shaping, which only learning sees:
        ``coverage_bonus`` per newly seen cell, ``on_target_bonus`` per agent on the target."""
        cfg = self.cfg
        if cfg.on_target_bonus > 0:
            rewards = rewards + cfg.on_target_bonus * info["on_target"].sum(axis=1)
        if cfg.coverage_bonus > 0 and "newly_seen" in info:
            rewards = rewards + cfg.coverage_bonus * info["newly_seen"]
        return rewards

    # ------------------------------------------------------------------ schedules
    def update_and_sync_target(self) -> None:
        """One gradient update; with PER, the priorities it measured (one per joint
        transition: the larger |δ| of the two agents); then the target networks: with
        ``target_update`` 0 a soft update θ⁻ ← θ⁻ + τ (θ − θ⁻), otherwise a hard copy of
        the online networks every ``target_update`` updates."""
        cfg, updates_before = self.cfg, self.updates
        self.update_networks(cfg.batch_size)
        if self.updates == updates_before:  # fewer transitions than a batch: no update
            return
        if cfg.prioritized:
            priorities = self.last_td_errors.abs().max(dim=0).values.numpy() + 1e-6
            self.replay_buffer.update_priorities(self.last_indices, priorities)
        with torch.no_grad():  # both networks' weights are one flat parameter each
            if cfg.target_update == 0:
                self.target.flat.lerp_(self.online.flat, cfg.target_tau)
            elif self.updates % cfg.target_update == 0:
                self.target.flat.copy_(self.online.flat)  # = load_state_dict(...)

    def progress(self) -> float:
        """Fraction of the training budget spent, in [0, 1]."""
        cfg = self.cfg
        if cfg.num_episodes > 0:
            return min(1.0, self.episodes / cfg.num_episodes)
        return min(1.0, self.env_steps / cfg.total_steps)

    def next_epsilon(self, finished_episodes: int) -> float:
        """ε after this step: with ``epsilon_decay`` > 0 the skeleton's multiplicative decay
        per finished episode, ε <- max(ε_end, ε · decay); otherwise linear from
        ``epsilon_start`` to ``epsilon_end`` over the first ``epsilon_fraction`` of the run."""
        cfg = self.cfg
        if cfg.epsilon_decay > 0:
            return max(cfg.epsilon_end, self.epsilon * cfg.epsilon_decay**finished_episodes)
        fraction = min(1.0, self.progress() / cfg.epsilon_fraction)
        return cfg.epsilon_start + fraction * (cfg.epsilon_end - cfg.epsilon_start)

    def learning_rate(self) -> float:
        """Linear from lr to lr * lr_end_factor over the run."""
        return self.cfg.lr * (1.0 + self.progress() * (self.cfg.lr_end_factor - 1.0))

    def budget_spent(self) -> bool:
        cfg = self.cfg
        if cfg.num_episodes > 0:
            return self.episodes >= cfg.num_episodes
        return self.env_steps >= cfg.total_steps

    # ------------------------------------------------------------------ the algorithm
    def train(self, progress: Callable[[dict[str, Any]], None] | None = None) -> list[dict]:
        """Collect with the vectorised environments and learn until the budget is spent;
        evaluate every ``eval_interval`` env steps (validation episodes), keep the best
        weights, save the models and the log. Returns the log rows."""
        cfg, rollout = self.cfg, self.rollout
        self.start_log()
        next_evaluation = 0
        update_credit = 0.0
        while not self.budget_spent():
            if self.env_steps >= next_evaluation:
                self.evaluate_and_log(progress)
                next_evaluation += cfg.eval_interval
            # 1. Act ε-greedily (messages with DIAL noise), 2. step all environment copies.
            actions, messages = self.act(rollout.obs, self.epsilon, self.rng, noisy_messages=True)
            next_obs, rewards, terminated, truncated, info = rollout.env.step(actions, messages)
            # 3. Store. Only "both on target" is terminal; the time limit is a cut-off.
            learned = self.learning_rewards(rewards, info)
            self.store(
                rollout, actions, messages, learned, info["final_obs"], terminated, truncated
            )
            finished = terminated | truncated
            self.recent_returns.extend(rollout.advance(next_obs, rewards, finished).tolist())
            self.recent_successes.extend(terminated[finished].tolist())
            n_finished = int(finished.sum())
            self.env_steps += rollout.env.n_envs
            self.episodes += n_finished
            # 4. Update if due: updates_per_step per step of the num_envs copies.
            if self.env_steps >= cfg.learning_starts:
                update_credit += cfg.updates_per_step * rollout.env.n_envs / cfg.num_envs
            while update_credit >= 1.0:
                update_credit -= 1.0
                # 5. Target networks: a soft update (or a hard copy every target_update).
                self.update_and_sync_target()
            # 6. Schedules.
            self.epsilon = self.next_epsilon(n_finished)
            for group in self.optimizer.param_groups:
                group["lr"] = self.learning_rate()
        # 7. Log the end, keep the best weights, save.
        self.evaluate_and_log(progress)
        if cfg.keep_best:
            self.online.load_state_dict(self.best_checkpoint().state)
        self.save_models()
        return self.log

    def train_episode(self) -> tuple[float, bool]:
        """Play one episode in a single environment, learning as :meth:`train` does;
        returns (episode_reward, success)."""
        if self._episode_rollout is None:
            self._episode_rollout = self.start_rollout(1, self.seed + 1)
        rollout, cfg = self._episode_rollout, self.cfg
        while True:
            actions, messages = self.act(rollout.obs, self.epsilon, self.rng, noisy_messages=True)
            next_obs, rewards, terminated, truncated, info = rollout.env.step(actions, messages)
            learned = self.learning_rewards(rewards, info)
            self.store(
                rollout, actions, messages, learned, info["final_obs"], terminated, truncated
            )
            finished = terminated | truncated
            returns = rollout.advance(next_obs, rewards, finished)
            self.env_steps += 1
            if self.env_steps >= cfg.learning_starts:
                self.update_and_sync_target()
            if finished[0]:
                self.episodes += 1
                self.epsilon = self.next_epsilon(1)
                return float(returns[0]), bool(terminated[0])


__all__ = ["EVAL_EPSILON", "MultiAgentTrainer", "apply_observation_mask", "config_from"]
