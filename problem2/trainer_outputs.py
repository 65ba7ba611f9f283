"""The evaluations and outputs of :class:`trainer.MultiAgentTrainer`: the periodic
evaluation on the validation episodes, the checkpoints it scores and the best of them
("selection"), the training log (rows in memory and a CSV file) and the exported
TorchScript pair.

:class:`TrainerOutputs` is a base class of ``MultiAgentTrainer``; the attributes it reads
are set by the trainer's ``__init__`` (listed in the class body).
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
from models import export_policy
from multi_agent_env import VectorMultiAgentEnv
from paired_networks import PairedQNetworks
from rollout import EVAL_EPSILON, EVAL_SEED, VALIDATION_SEED, evaluate_policy, select_best
from train_config import TrainConfig

LOG_FIELDS = (
    "env_steps", "episodes", "updates", "epsilon", "loss", "mean_q", "train_return",
    "train_success", "eval_success_greedy", "eval_success_eps", "eval_return_greedy",
    "eval_return_eps", "eval_steps_greedy", "eval_steps_eps",
)  # fmt: skip


@dataclass
class Checkpoint:
    """The weights of one periodic evaluation and their results on the validation episodes
    (:func:`rollout.summarize` dicts, greedy and at epsilon = 0.05)."""

    env_steps: int
    greedy: dict[str, Any]
    eps: dict[str, Any]
    state: dict[str, torch.Tensor]


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
    checkpoints: list[Checkpoint]
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
            env_steps=self.env_steps, episodes=self.episodes, updates=self.updates,
            epsilon=round(self.epsilon, 6), loss=mean(self._losses), mean_q=mean(self._mean_qs),
            train_return=mean(self.recent_returns), train_success=mean(self.recent_successes),
            eval_success_greedy=greedy["success_rate"], eval_success_eps=eps["success_rate"],
            eval_return_greedy=greedy["mean_return"], eval_return_eps=eps["mean_return"],
            eval_steps_greedy=steps(greedy), eval_steps_eps=steps(eps),
        )  # fmt: skip
        self._losses, self._mean_qs = [], []
        self.log.append(row)
        with open(self.log_path, "a", newline="", encoding="utf-8") as handle:
            csv.DictWriter(handle, LOG_FIELDS, lineterminator="\n").writerow(row)
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
    def best_env_steps(self) -> int:
        """Environment steps at the best checkpoint (0 before the first evaluation)."""
        best = self.best_checkpoint()
        return 0 if best is None else best.env_steps

    @property
    def best_selection(self) -> dict[str, float]:
        """Validation success rates of the best checkpoint, ``greedy`` and ``eps``."""
        best = self.best_checkpoint()
        return (
            {} if best is None else {c: getattr(best, c)["success_rate"] for c in ("greedy", "eps")}
        )

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
