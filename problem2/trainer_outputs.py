"""The evaluations and outputs of :class:`trainer.MultiAgentTrainer`: the periodic
evaluation on the validation episodes, the best weights so far ("selection"), the training
log (rows in memory and a CSV file) and the exported TorchScript pair.

:class:`TrainerOutputs` is a base class of ``MultiAgentTrainer``; the attributes it reads
are set by the trainer's ``__init__`` (listed in the class body).
"""

from __future__ import annotations

import csv
import math
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from models import export_policy
from multi_agent_env import VectorMultiAgentEnv
from paired_networks import PairedQNetworks
from rollout import EVAL_EPSILON, EVAL_SEED, VALIDATION_SEED, evaluate_policy, selection_score
from train_config import TrainConfig

LOG_FIELDS = (
    "env_steps", "episodes", "updates", "epsilon", "loss", "mean_q", "train_return",
    "train_success", "eval_success_greedy", "eval_success_eps", "eval_return_greedy",
    "eval_return_eps", "eval_length_greedy", "eval_length_eps",
)  # fmt: skip


class TrainerOutputs:
    """Evaluation, selection of the best weights, the log and the model files (a base class
    of the trainer; the evaluations play :meth:`trainer_acting.TrainerActing.policy` in
    environments from its ``make_vector_env``)."""

    # Set by MultiAgentTrainer.__init__ (and counted by its training loop):
    cfg: TrainConfig
    mode: str
    name: str  # <mode>_seed<seed>, the stem of every file of the run
    models_dir: Path
    logs_dir: Path
    online: PairedQNetworks
    epsilon: float
    env_steps: int
    episodes: int
    updates: int
    recent_returns: deque[float]
    recent_successes: deque[bool]
    log: list[dict[str, Any]]
    _losses: list[float]
    _mean_qs: list[float]
    best_score: float
    best_env_steps: int
    best_selection: dict[str, float]
    _best_state: dict[str, torch.Tensor]
    _evaluation_envs: dict[int, VectorMultiAgentEnv]

    def evaluate(
        self, num_episodes: int = 10, epsilon: float = 0.0, seed: int = EVAL_SEED
    ) -> tuple[float, float]:
        """(mean reward, success rate) over fixed episodes (the test episodes by default),
        under the reward the trainer learns from (unshaped); on the validation maps when
        training on a map pool."""
        summary = self.evaluation_summary(num_episodes, epsilon, seed)
        return summary["mean_return"], summary["success_rate"]

    def evaluation_summary(
        self, num_episodes: int, epsilon: float, seed: int
    ) -> dict[str, float | int | None]:
        """:func:`rollout.evaluate_policy` of the current policy on fixed episodes drawn
        from ``seed``, in environments made once per run (each evaluation reseeds them)."""
        n_envs = min(num_episodes, 500)
        if n_envs not in self._evaluation_envs:
            self._evaluation_envs[n_envs] = self.make_vector_env(n_envs, None, validation=True)
        env = self._evaluation_envs[n_envs]
        return evaluate_policy(env, self.policy(epsilon), num_episodes, seed=seed)

    def evaluate_and_log(self, progress: Callable[[dict[str, Any]], None] | None) -> None:
        """Evaluate on the validation episodes, remember the best weights ("selection"),
        append a row to the log and its CSV file."""
        episodes = self.cfg.eval_episodes
        greedy = self.evaluation_summary(episodes, 0.0, VALIDATION_SEED)
        eps = self.evaluation_summary(episodes, EVAL_EPSILON, VALIDATION_SEED)
        selection = {"greedy": greedy["success_rate"], "eps": eps["success_rate"]}
        selection["score"] = selection_score(greedy, eps, self.cfg.select_by)
        if selection["score"] > self.best_score:
            self.best_score, self.best_env_steps = selection["score"], self.env_steps
            self.best_selection = selection
            self._best_state = {k: v.clone() for k, v in self.online.state_dict().items()}

        def mean(values: Any) -> float:
            return float(np.mean(values)) if len(values) else math.nan

        row = dict(
            env_steps=self.env_steps, episodes=self.episodes, updates=self.updates,
            epsilon=round(self.epsilon, 6), loss=mean(self._losses), mean_q=mean(self._mean_qs),
            train_return=mean(self.recent_returns), train_success=mean(self.recent_successes),
            eval_success_greedy=greedy["success_rate"], eval_success_eps=eps["success_rate"],
            eval_return_greedy=greedy["mean_return"], eval_return_eps=eps["mean_return"],
            eval_length_greedy=greedy["mean_length"], eval_length_eps=eps["mean_length"],
        )  # fmt: skip
        self._losses, self._mean_qs = [], []
        self.log.append(row)
        with open(self.log_path, "a", newline="", encoding="utf-8") as handle:
            csv.DictWriter(handle, LOG_FIELDS, lineterminator="\n").writerow(row)
        if progress:
            progress(row)

    @property
    def log_path(self) -> Path:
        return self.logs_dir / f"{self.name}.csv"

    def start_log(self) -> None:
        """Create the log file with its header (replacing an older one)."""
        self.logs_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, "w", newline="", encoding="utf-8") as handle:
            csv.DictWriter(handle, LOG_FIELDS, lineterminator="\n").writeheader()

    def save_models(self) -> list[Path]:
        """Export both agents (TorchScript, mask inside) as ``<mode>_seed<seed>_agent_X.pt``."""
        return [
            export_policy(
                self.online.agent(index), self.mode, self.models_dir / f"{self.name}_agent_{a}.pt"
            )
            for index, a in enumerate("AB")
        ]
