"""The course skeleton's interface of the trainer, kept apart from the training loop.

The skeleton builds ``MultiAgentTrainer(env, args)`` from a bare ``argparse.Namespace``,
acts one agent at a time with :meth:`~CourseSkeletonAPI.select_action`, trains episode by
episode with :meth:`~CourseSkeletonAPI.train_episode` and reads ``network_A`` /
``network_B``. ``python train.py`` uses none of this: it runs ``MultiAgentTrainer.train``.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np
import torch
from grid_maps import NUM_ACTIONS
from rollout import EVAL_SEED
from train_config import TrainConfig


def config_from(args: Any) -> TrainConfig:
    """A TrainConfig as given (validated by its maker: the CLI, ``run_experiments``), or
    one built and validated from any namespace, e.g. the course skeleton's (``mode``
    missing or ``all`` means ``full``; output under ``./results``; unknown attributes and
    ``grid_size`` ignored: the map comes from the environment)."""
    if isinstance(args, TrainConfig):
        return args
    known = {f.name for f in fields(TrainConfig)}
    settings = {k: v for k, v in vars(args).items() if k in known and v is not None}
    if settings.get("mode", "all") == "all":
        settings["mode"] = "full"
    settings.setdefault("output_dir", "results")  # like the skeleton
    settings.pop("grid_size", None)  # the trainer trains on env's grid
    return TrainConfig(**settings).validate()


class CourseSkeletonAPI:
    """The skeleton's methods, mixed into :class:`trainer.MultiAgentTrainer`."""

    _episode_rollout: Any = None  # the one-environment rollout of train_episode()

    @property
    def network_A(self) -> torch.nn.Module:
        """Agent A's network as a standalone AgentDQN / DuelingDQN (a snapshot)."""
        return self.online.agent(0)

    @property
    def network_B(self) -> torch.nn.Module:
        return self.online.agent(1)

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

    def train_episode(self) -> tuple[float, bool]:
        """Play one episode in a single environment, learning as ``train`` does but with one
        gradient update per env step (the skeleton's loop); returns (episode_reward, success)."""
        if self._episode_rollout is None:
            self._episode_rollout = self.start_rollout(1, self.seed + 1)
        while True:
            returns, successes, finished = self.collect(self._episode_rollout)
            if self.env_steps >= self.cfg.learning_starts:
                self.update_networks(self.cfg.batch_size)
            self.update_schedules(int(finished.sum()))
            if len(returns):
                return float(returns[0]), bool(successes[0])

    def evaluate(
        self, num_episodes: int = 10, epsilon: float = 0.0, seed: int = EVAL_SEED
    ) -> tuple[float, float]:
        """(mean reward, success rate) over fixed episodes (the test episodes by default),
        under the reward the trainer learns from (unshaped); on the validation maps when
        training on a map pool."""
        summary = self.evaluation_summary(num_episodes, epsilon, seed)
        return summary["mean_return"], summary["success_rate"]
