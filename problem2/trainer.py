"""Independent DQN for two agents that must meet on a target, with a learned message.

Each agent has its own network (a Q head over 5 moves and a sigmoid message head) and learns
from a shared replay of joint transitions: a Huber TD loss summed over both agents, target
networks, a Double-DQN target, gradient clipping. The message is trained DIAL-style, through
the receiver's TD loss (:meth:`DQNTrainer.splice_messages`). The ablation modes differ only
in the input mask (``models.observation_mask``) applied wherever a network sees an observation.

:meth:`DQNTrainer.train` is the loop, in DQN order: act (ε-greedy) → step → store → update
(``td_loss`` → ``backward()`` → clip → Adam → target sync) → schedules → evaluate and log.
``train.MultiAgentTrainer`` adds the course skeleton's interface. Studies subclass it through
``make_vector_env``, ``input_mask``, ``learning_rewards``, ``sample``, ``after_backward`` and
``export_agent``.
"""

from __future__ import annotations

import csv
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from models import AgentDQN, PairedQNetworks, export_policy, observation_mask
from replay import ReplayBuffer, TransitionBatch, sample_batch
from rollout import (
    EVAL_EPSILON,
    EVAL_SEED,
    VALIDATION_SEED,
    PolicyFn,
    Rollout,
    run_episodes,
    select_best,
    validation_summary,
)
from settings import TRAINABLE_MODES, TrainConfig
from vector_env import NUM_ACTIONS, TARGET, VectorMultiAgentEnv

LAST_WEIGHTS = "last_weights"  # subfolder of agent_models/: each run's final weights (keep_best)


def step_fields(
    obs: np.ndarray, actions: np.ndarray, messages: np.ndarray
) -> dict[str, np.ndarray]:
    """The course's fields of the transitions starting now: obs (N, 2, D), actions and
    messages (N, 2) as ``state_A``, ``state_B``, ``action_A``, ... ``comm_B``."""
    return {
        "state_A": obs[:, 0],
        "state_B": obs[:, 1],
        "action_A": actions[:, 0],
        "action_B": actions[:, 1],
        "comm_A": messages[:, 0],
        "comm_B": messages[:, 1],
    }


@dataclass
class Checkpoint:
    """The weights of one periodic evaluation and their validation results (greedy, ε = 0.05)."""

    env_steps: int
    greedy: dict[str, Any]
    eps: dict[str, Any]
    state: dict[str, torch.Tensor]


class DQNTrainer:
    """Trains agents A and B of one ablation mode with one seed.

    Args:
        env: what training reads of the environment: its ``grid`` (H, W), ``obs_window`` and
            ``max_steps`` (a ``MultiAgentEnv`` or a one-map ``VectorMultiAgentEnv``).
        cfg: the run's settings, checked (``settings.validated``); ``cfg.mode`` one of
            independent, comm, distance, full; outputs go to ``<cfg.output_dir>/agent_models``
            and ``/training_logs``.
    """

    def __init__(self, env: Any, cfg: TrainConfig) -> None:
        self.cfg = cfg
        if cfg.mode not in TRAINABLE_MODES:
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
        self.mask = self.input_mask()  # (D,)
        # The partner's message is the second-to-last input: element w² of an observation
        # (models.MESSAGE_INDEX for 3 x 3), and an agent with memory keeps message and
        # distance last too.
        message_index = self.obs_dim - 2
        self.message_column = torch.arange(self.obs_dim) == message_index  # (D,)
        sizes = (self.obs_dim, cfg.hidden_dim, NUM_ACTIONS, self.network_class)
        self.online, self.target = PairedQNetworks(*sizes), PairedQNetworks(*sizes)
        self.target.load_state_dict(self.online.state_dict())
        self.target.requires_grad_(False)
        self.target_parameters = list(self.target.parameters())
        self.online_parameters = list(self.online.parameters())  # both agents' weights
        self.optimizer = torch.optim.Adam(self.online_parameters, lr=cfg.lr, fused=True)
        self.replay_buffer = ReplayBuffer(cfg.buffer_size, seed=self.seed, gamma=cfg.gamma)
        # DIAL trains the message where the receiver sees it (comm, full).
        self.dial = cfg.comm_learning == "dial" and bool(self.mask[message_index])
        self.epsilon = cfg.epsilon_start
        self.env_steps = self.episodes = self.updates = 0
        self.recent_returns: deque[float] = deque(maxlen=100)
        self.recent_successes: deque[bool] = deque(maxlen=100)
        self.log: list[dict[str, Any]] = []
        self._losses: list[float] = []
        self._mean_qs: list[float] = []
        self.checkpoints: list[Checkpoint] = []  # one per periodic evaluation
        self._evaluation_envs: dict[int, VectorMultiAgentEnv] = {}  # by number of copies

    # ------------------------------------------------------------------ the loop
    def train(self, progress: Callable[[dict[str, Any]], None] | None = None) -> list[dict]:
        """Collect with the vectorised environments and learn until the budget is spent;
        evaluate every ``eval_interval`` env steps (validation episodes), keep the best
        weights, save the models and the log. Returns the log rows."""
        cfg, rollout = self.cfg, self.rollout
        self.start_log()
        next_evaluation = 0
        while not self.budget_spent():
            if self.env_steps >= next_evaluation:  # 6. Evaluate and log.
                self.evaluate_and_log(progress)
                next_evaluation += cfg.eval_interval
            # 1. Act ε-greedily, 2. step the N environment copies, 3. store the transitions.
            _, _, finished = self.collect(rollout)
            # 4. Update both agents' networks (TD loss, backward, clip, Adam), then the targets.
            if self.env_steps >= cfg.learning_starts:
                for _ in range(cfg.updates_per_step):
                    self.update_networks(cfg.batch_size)
            # 5. Schedules: ε and the learning rate.
            self.update_schedules(int(finished.sum()))
        self.evaluate_and_log(progress)
        if cfg.keep_best:  # the weights the run ended with stay beside the selected ones
            self.save_models(self.models_dir / LAST_WEIGHTS)
            self.online.load_state_dict(self.best_checkpoint().state)
        self.save_models()
        return self.log

    # ------------------------------------------------------------------ the environments
    vector_env_class: type[VectorMultiAgentEnv] = VectorMultiAgentEnv  # a study may extend it
    network_class: type[AgentDQN] = AgentDQN  # each agent's network

    def make_vector_env(
        self, n_envs: int, seed: int | None, validation: bool = False
    ) -> VectorMultiAgentEnv:
        """``n_envs`` copies of the training map with the reward the trainer learns from
        (``validation``: for the periodic evaluations; the same map here)."""
        return self.vector_env_class(
            n_envs,
            grid=self.env.grid,
            obs_window=self.env.obs_window,
            max_steps=self.env.max_steps,
            seed=seed,
            reward_mode=self.cfg.reward_mode,
        )

    def input_mask(self) -> torch.Tensor:
        """The (D,) multiplicative mask of the network's input (the mode's observation mask;
        an agent whose input holds more than the observation may hide more)."""
        return torch.tensor(observation_mask(self.mode, self.obs_dim))

    def start_rollout(self, n_envs: int, seed: int | None) -> Rollout:
        return Rollout.start(self.make_vector_env(n_envs, seed), self.cfg.n_step, self.cfg.gamma)

    # ------------------------------------------------------------------ 1-3. act, step, store
    def act(
        self, obs: np.ndarray, epsilon: float, rng: np.random.Generator, noisy_messages: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """obs (N, 2, D) -> ε-greedy actions (N, 2) int64 and messages (N, 2) float32."""
        with torch.inference_mode():
            q_values, logits = self.online(torch.from_numpy(obs).transpose(0, 1) * self.mask)
            logits = logits[..., 0]  # (2, N)
            if noisy_messages:
                logits = self.with_noise(logits)
            messages = torch.sigmoid(logits).T.numpy()
        actions = q_values.numpy().argmax(axis=-1).T  # the first best, as torch.max picks
        if epsilon > 0:  # a greedy policy draws nothing
            explore = rng.random(actions.shape) < epsilon
            actions = np.where(explore, rng.integers(0, NUM_ACTIONS, actions.shape), actions)
        return actions, messages

    def policy(self, epsilon: float = 0.0, seed: int = EVAL_SEED) -> PolicyFn:
        """The current greedy/ε-greedy policy as a function for :func:`rollout.run_episodes`."""
        rng = np.random.default_rng(seed)
        return lambda obs, positions: self.act(obs, epsilon, rng, noisy_messages=False)

    def learning_rewards(
        self, rewards: np.ndarray, info: dict[str, np.ndarray], obs: np.ndarray
    ) -> np.ndarray:
        """The team rewards (N,) plus the terms only learning sees: with ``potential_credit``
        team, the arrival term γ Φ(s') − Φ(s), Φ = ``target_potential`` per agent on the
        target (``obs`` (N, 2, D) before the step; with ``agent`` :meth:`td_loss` adds each
        agent's own). The arrival term pays +Φ per arrival and charges Φ per departure, so
        leaving and coming back earns nothing; being potential-based, it keeps the optimal
        policy of the goal reward."""
        cfg = self.cfg
        if cfg.target_potential > 0 and cfg.potential_credit == "team":
            before = self.on_target(obs).sum(axis=1)
            after = info["on_target"].sum(axis=1)
            rewards = rewards + cfg.target_potential * (cfg.gamma * after - before)
        return rewards

    def on_target(self, obs: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """1 where an agent stands on the target: the centre of its patch (obs (..., D),
        NumPy or torch) shows it."""
        return obs[..., self.env.obs_window**2 // 2] == TARGET

    def collect(self, rollout: Rollout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step of the N environment copies of ``rollout``: act, step, store. Returns the
        returns and successes of the episodes that ended, and which copies finished (N,)."""
        actions, messages = self.act(rollout.obs, self.epsilon, self.rng, noisy_messages=True)
        next_obs, rewards, terminated, truncated, info = rollout.env.step(actions, messages)
        # Only "both on target" is terminal; the time limit is a cut-off.
        learned = self.learning_rewards(rewards, info, rollout.obs)
        self.store(rollout, actions, messages, learned, info["final_obs"], terminated, truncated)
        finished = terminated | truncated
        returns = rollout.advance(next_obs, rewards, finished)
        self.env_steps += rollout.env.n_envs
        self.episodes += int(finished.sum())
        self.recent_returns.extend(returns.tolist())
        self.recent_successes.extend(terminated[finished].tolist())
        return returns, terminated[finished], finished

    def store(
        self,
        rollout: Rollout,
        actions: np.ndarray,
        messages: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> None:
        """Push the joint transitions this step of the N episodes completes
        (:class:`rollout.NStepWindow`), each with both agents' observations one step before
        its start (DIAL); ``next_obs`` is the true one also where an episode was cut off."""
        obs = rollout.obs
        start = step_fields(obs, actions, messages) | {
            "prev_state_A": rollout.prev_obs[:, 0],
            "prev_state_B": rollout.prev_obs[:, 1],
            "has_prev": rollout.has_prev,
        }
        finished = terminated | truncated
        complete = rollout.window.add(start, rewards, next_obs, obs, terminated, finished)
        if len(complete["reward"]):
            self.replay_buffer.push_batch(**complete)

    # ------------------------------------------------------------------ 4. update
    def update_networks(self, batch_size: int) -> float:
        """One gradient step of both agents on a replay batch, then the target networks:
        with ``target_update`` 0 a soft update θ⁻ ← θ⁻ + τ (θ − θ⁻), otherwise a hard copy
        every ``target_update`` updates. Returns the loss (0.0, and no update, while the
        buffer holds fewer than ``batch_size`` transitions)."""
        if len(self.replay_buffer) < batch_size:
            return 0.0
        batch = self.sample(batch_size)
        loss, _, q_taken = self.td_loss(batch)
        self.optimizer.zero_grad()
        loss.backward()
        self.after_backward()
        torch.nn.utils.clip_grad_norm_(self.online_parameters, self.cfg.max_grad_norm, foreach=True)
        self.optimizer.step()
        self.updates += 1
        self.sync_target()
        loss_value = float(loss.detach())
        self._losses.append(loss_value)
        self._mean_qs.append(float(q_taken.mean()))
        return loss_value

    def sample(self, batch_size: int) -> TransitionBatch:
        """A uniform batch of ``batch_size`` transitions from the replay buffer."""
        return sample_batch(self.replay_buffer, batch_size, self.cfg.gamma)

    def after_backward(self) -> None:
        """Called between ``backward()`` and the gradient clipping (a study may change the
        gradients here, e.g. to share weights)."""

    def td_loss(self, batch: TransitionBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The Huber TD loss, summed over both agents (the assignment's L = L_A + L_B), on
        ``batch`` (obs (2, B, D), actions (2, B), reward, discount (B,)):

            y = R + d · Q_target(s', argmax_a Q_online(s', a))        (Double DQN)
                − α (max_b Q_target(s, b) − Q_target(s, a))           (advantage learning)
                + the agent's own arrival term             (:meth:`own_arrival_term`)

        R = r_t + γ r_{t+1} + ... + γ^(k-1) r_{t+k-1} is the k-step return (k <= n, fewer
        where the episode ends first) and d = γ^k, 0 where both agents reached the target
        (the only terminal: the time limit is a cut-off and is bootstrapped through); α
        rises over the run (:meth:`advantage_learning_alpha`). Returns (loss with gradient,
        TD errors δ (2, B), Q(s, a) (2, B)), the last two detached."""
        obs, next_obs = batch.obs * self.mask, batch.next_obs * self.mask
        if self.dial:
            obs, next_obs = self.splice_messages(batch, obs, next_obs)
        alpha, batch_size = self.advantage_learning_alpha(), obs.shape[1]
        with torch.no_grad():
            best_next = self.online(next_obs)[0].max(dim=-1, keepdim=True).indices
            # One target-network pass over s' and, for advantage learning, s: (2, B or 2B, 5).
            q_target = self.target(torch.cat([next_obs, obs], dim=1) if alpha > 0 else next_obs)[0]
            next_value = q_target[:, :batch_size].gather(-1, best_next)[..., 0]
            target = batch.reward + batch.discount * next_value + self.own_arrival_term(batch)
            if alpha > 0:
                q_at_s = q_target[:, batch_size:]
                taken = q_at_s.gather(-1, batch.actions.unsqueeze(-1))[..., 0]
                target = target - alpha * (q_at_s.max(dim=-1).values - taken)
        q_taken = self.online(obs)[0].gather(-1, batch.actions.unsqueeze(-1))[..., 0]
        loss = F.smooth_l1_loss(q_taken, target, reduction="none").mean(dim=1).sum()
        return loss, (q_taken - target).detach(), q_taken.detach()

    def own_arrival_term(self, batch: TransitionBatch) -> torch.Tensor | float:
        """With ``potential_credit`` agent, each agent's own arrival term over the k steps,
        Φ (d · on(s') − on(s)) (2, B): the sum of γ^j (γ Φ(s_{j+1}) − Φ(s_j)) telescopes,
        and the terminal state's potential is 0. Otherwise 0."""
        if self.cfg.target_potential == 0 or self.cfg.potential_credit != "agent":
            return 0.0
        on_now, on_next = (self.on_target(o).float() for o in (batch.obs, batch.next_obs))
        return self.cfg.target_potential * (batch.discount * on_next - on_now)

    def splice_messages(
        self, batch: TransitionBatch, obs: torch.Tensor, next_obs: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """DIAL: replace the incoming messages (element w²) of masked ``obs`` and
        ``next_obs`` (2, B, D) by recomputed ones. At time t agent A received the message B
        sent from its observation at t-1 (``prev_obs[1]``): recomputed by B's online network,
        with gradient and noise on the logit, it lets A's TD loss train B's message head (and
        vice versa). Without a stored previous observation (an episode start, a transition
        pushed by hand) the stored message stays. The message in s' comes from the partner's
        target network on its observation one step before s' (``last_obs``), no gradient."""
        _, logits = self.online(batch.prev_obs * self.mask)
        logits = self.with_noise(logits)
        with torch.no_grad():
            next_received = torch.sigmoid(self.target(batch.last_obs * self.mask)[1]).flip(0)
        # (2, B, 1) messages written into the message column (D,): where a previous
        # observation is stored for s, always for s'.
        spliced = self.message_column & (batch.has_prev.view(1, -1, 1) > 0)  # (1, B, D)
        obs = torch.where(spliced, torch.sigmoid(logits).flip(0), obs)
        return obs, torch.where(self.message_column, next_received, next_obs)

    def with_noise(self, logits: torch.Tensor) -> torch.Tensor:
        """DIAL's noise on message logits: + ``comm_noise`` · N(0, 1) (none at 0)."""
        if self.cfg.comm_noise == 0:
            return logits
        return logits + self.cfg.comm_noise * torch.randn(logits.shape, generator=self.noise_rng)

    def sync_target(self) -> None:
        """Move the target networks towards the online ones (soft) or copy them when due."""
        if self.cfg.target_update == 0:
            pairs = zip(self.target_parameters, self.online_parameters, strict=True)
            with torch.no_grad():
                for target, online in pairs:
                    target.lerp_(online, self.cfg.target_tau)
        elif self.updates % self.cfg.target_update == 0:
            self.target.load_state_dict(self.online.state_dict())

    # ------------------------------------------------------------------ 5. schedules
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

    def advantage_learning_alpha(self) -> float:
        """α of advantage learning: linear from 0 to ``advantage_learning`` over the first
        ``advantage_learning_ramp`` of the run, then constant."""
        cfg = self.cfg
        return cfg.advantage_learning * min(1.0, self.progress() / cfg.advantage_learning_ramp)

    def learning_rate(self) -> float:
        """Linear from lr to lr * lr_end_factor over the run."""
        return self.cfg.lr * (1.0 + self.progress() * (self.cfg.lr_end_factor - 1.0))

    def budget_spent(self) -> bool:
        return self.progress() >= 1.0

    def update_schedules(self, finished_episodes: int) -> None:
        """ε and the learning rate after a step in which ``finished_episodes`` ended."""
        self.epsilon = self.next_epsilon(finished_episodes)
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate()

    # ------------------------------------------------------------------ 6. evaluate and log
    def evaluation_summary(
        self, num_episodes: int, epsilon: float, seed: int
    ) -> dict[str, float | int | None]:
        """:func:`rollout.summarize` of the current policy on fixed episodes drawn from
        ``seed``, with the mean return under the assignment's table on the same episodes
        (``mean_table_return``), in environments made once per run (reseeded each time)."""
        env = self.evaluation_env(num_episodes)
        results = run_episodes(env, self.evaluation_policy(env, epsilon), num_episodes, seed=seed)
        return validation_summary(results)

    def evaluation_policy(self, env: VectorMultiAgentEnv, epsilon: float) -> PolicyFn:
        """The policy the evaluations play in ``env`` (an agent with memory needs ``env``)."""
        return self.policy(epsilon)

    def evaluation_env(self, num_episodes: int) -> VectorMultiAgentEnv:
        """The environments that play ``num_episodes`` evaluation episodes, made once per run
        (each evaluation reseeds them)."""
        n_envs = min(num_episodes, 500)  # more copies than this gain no speed, only memory
        if n_envs not in self._evaluation_envs:
            self._evaluation_envs[n_envs] = self.make_vector_env(n_envs, None, validation=True)
        return self._evaluation_envs[n_envs]

    def evaluate_and_log(self, progress: Callable[[dict[str, Any]], None] | None) -> None:
        """Evaluate on the validation episodes, keep the weights with their results as a
        checkpoint, append a row to the log and its CSV file."""
        episodes = self.cfg.eval_episodes
        greedy = self.evaluation_summary(episodes, 0.0, VALIDATION_SEED)
        eps = self.evaluation_summary(episodes, EVAL_EPSILON, VALIDATION_SEED)
        state = {k: v.clone() for k, v in self.online.state_dict().items()}
        self.checkpoints.append(Checkpoint(self.env_steps, greedy, eps, state))

        def mean(values: Any) -> float:
            return float(np.mean(values)) if len(values) else math.nan

        def steps(summary: dict[str, Any]) -> float:
            value = summary["mean_steps_to_success"]
            return math.nan if value is None else value

        row = dict(
            env_steps=self.env_steps,
            episodes=self.episodes,
            updates=self.updates,
            epsilon=round(self.epsilon, 6),
            loss=mean(self._losses),
            mean_q=mean(self._mean_qs),
            train_return=mean(self.recent_returns),
            train_success=mean(self.recent_successes),
            eval_success_greedy=greedy["success_rate"],
            eval_success_eps=eps["success_rate"],
            eval_return_greedy=greedy["mean_return"],
            eval_return_eps=eps["mean_return"],
            eval_return_table_greedy=greedy["mean_table_return"],
            eval_return_table_eps=eps["mean_table_return"],
            eval_steps_greedy=steps(greedy),
            eval_steps_eps=steps(eps),
        )
        self._losses, self._mean_qs = [], []
        with open(self.log_path, "a", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, list(row), lineterminator="\n")
            if not self.log:  # the row's keys are the columns
                writer.writeheader()
            writer.writerow(row)
        self.log.append(row)
        if progress:
            progress(row)

    def best_checkpoint(self) -> Checkpoint | None:
        """The checkpoint that ``cfg.select_by`` picks (:func:`rollout.select_best`), or None
        before the first evaluation."""
        if not self.checkpoints:
            return None
        pairs = [(c.greedy, c.eps) for c in self.checkpoints]
        return self.checkpoints[select_best(pairs, self.cfg.select_by)]

    @property
    def log_path(self) -> Path:
        return self.logs_dir / f"{self.name}.csv"

    def start_log(self) -> None:
        """Create the log file empty (replacing an older one); the first row writes the header."""
        self.logs_dir.mkdir(parents=True, exist_ok=True)
        self.log_path.write_bytes(b"")

    def save_models(self, folder: Path | None = None) -> list[Path]:
        """Write both agents as policy files ``<mode>_seed<seed>_agent_{A,B}.pt`` into
        ``folder`` (default: ``models_dir``) and return the paths. ``train`` calls it with the
        run's last weights (``last_weights/``, with ``keep_best``) and with the weights it ends
        with."""
        folder = self.models_dir if folder is None else folder
        return [
            self.export_agent(i, folder / f"{self.name}_agent_{a}.pt") for i, a in enumerate("AB")
        ]

    def export_agent(self, index: int, path: Path) -> Path:
        """Write agent ``index``: its network behind the mode's mask, as TorchScript
        (:func:`models.export_policy`; a study's agents may take another form)."""
        return export_policy(self.online.agent(index), self.mode, path)
