"""Hyperparameters of Problem 2's training, in one dataclass that also builds the CLI.

Each field's one-line docstring is its ``--help`` text. Every flag is accepted
with underscores (the course's spelling, ``--num_episodes``) and with dashes
(``--num-episodes``).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
from dataclasses import dataclass, field
from typing import Any

MODES = ("independent", "comm", "full")


@dataclass
class TrainConfig:
    """Everything that defines a training run (one mode, one seed) or a batch of them."""

    mode: str = "all"
    """independent (patch only), comm (+ message), full (+ distance), all, or a list: comm,full"""
    seed: int = 641
    """first training seed; runs use seed, seed + 1, ... unless --seeds is given"""
    num_seeds: int = 5
    """number of training seeds per mode"""
    seeds: list[int] = field(default_factory=list)
    """explicit training seeds (overrides --seed and --num_seeds)"""
    map_seed: int = 641
    """seed of the map (obstacles and target) that every run trains on"""
    grid_size: int = 10
    """side of the square grid"""
    max_steps: int = 50
    """episode time limit (a cut-off, not a terminal state: the TD target bootstraps through it)"""
    reward_mode: str = "arrival"
    """arrival (+2 once per agent on first arrival) or per_step (the literal +2 every step)"""
    total_steps: int = 200_000
    """environment steps per run, summed over the parallel environments"""
    num_episodes: int = 0
    """if positive, train for this many finished episodes instead of --total_steps"""
    num_envs: int = 64
    """parallel environments that collect experience"""
    batch_size: int = 256
    """transitions per gradient update"""
    lr: float = 5e-4
    """Adam learning rate at the start"""
    lr_end_factor: float = 0.1
    """final learning rate as a fraction of lr, reached linearly at the end of the run"""
    gamma: float = 0.99
    """discount factor"""
    epsilon_start: float = 1.0
    """initial exploration rate"""
    epsilon_end: float = 0.05
    """final exploration rate"""
    epsilon_decay: float = 0.0
    """the course skeleton's multiplicative decay of epsilon per finished episode (e.g. 0.995:
    epsilon <- max(epsilon_end, epsilon * 0.995)); 0 = linear schedule (see epsilon_fraction)"""
    hidden_dim: int = 64
    """units of the hidden layer"""
    target_update: int = 100
    """gradient updates (not env steps) between hard copies of the online into the target
    networks"""
    buffer_size: int = 100_000
    """replay capacity in joint transitions"""
    learning_starts: int = 5_000
    """environment steps collected before the first update"""
    updates_per_step: int = 2
    """gradient updates per step of the parallel environments"""
    max_grad_norm: float = 10.0
    """gradient-norm clipping threshold"""
    comm_learning: str = "dial"
    """dial: train the message head through the partner's TD loss; none: leave it untrained"""
    comm_noise: float = 1.0
    """standard deviation of the Gaussian noise on the message logit during training (DIAL)"""
    dueling: bool = False
    """use the dueling architecture Q = V + (A - mean A)"""
    prioritized: bool = False
    """use proportional prioritised replay"""
    eval_interval: int = 10_000
    """environment steps between evaluations on the fixed evaluation episodes"""
    eval_episodes: int = 200
    """episodes of each periodic evaluation (fixed validation episodes)"""
    keep_best: bool = True
    """end with the weights that scored best in the periodic evaluations, not the last ones"""
    final_eval_episodes: int = 1000
    """episodes of the final evaluation that picks the best seed per mode"""
    save_freq: int = 0
    """environment steps between intermediate model saves (0: save at the end only)"""
    output_dir: str = "results"
    """folder (relative to problem2/) for agent_models/ and training_logs/"""
    workers: int = 2
    """parallel training processes (one per core)"""
    epsilon_fraction: float = 0.3
    """fraction of the run over which epsilon falls linearly from start to end"""
    select_by: str = "success"
    """checkpoint selection on validation episodes: success (mean of greedy and epsilon
    success) or return (mean validation return under the trained reward)"""

    def run_seeds(self) -> list[int]:
        return list(self.seeds) if self.seeds else [self.seed + i for i in range(self.num_seeds)]

    def run_modes(self) -> list[str]:
        return list(MODES) if self.mode == "all" else self.mode.split(",")

    def validate(self) -> TrainConfig:
        """Raise ValueError naming the first invalid setting; return self."""
        checks = [
            (
                self.mode == "all" or set(self.mode.split(",")) <= set(MODES),
                f"mode must be all or a comma-separated list of {MODES}",
            ),
            (
                self.reward_mode in ("arrival", "per_step"),
                "reward_mode must be arrival or per_step",
            ),
            (self.comm_learning in ("dial", "none"), "comm_learning must be dial or none"),
            (0.0 <= self.gamma < 1.0, "gamma must lie in [0, 1)"),
            (
                0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0,
                "need 0 <= epsilon_end <= epsilon_start <= 1",
            ),
            (
                0.0 <= self.epsilon_decay < 1.0,
                "epsilon_decay is a multiplicative factor per episode in (0, 1), or 0 for the "
                "linear schedule over epsilon_fraction of the run",
            ),
            (0.0 < self.epsilon_fraction <= 1.0, "epsilon_fraction must lie in (0, 1]"),
            (self.select_by in ("success", "return"), "select_by must be success or return"),
            (self.total_steps > 0 or self.num_episodes > 0, "give total_steps or num_episodes"),
            (
                self.batch_size > 0 and self.num_envs > 0 and self.hidden_dim > 0,
                "batch_size, num_envs and hidden_dim must be positive",
            ),
            (self.buffer_size >= self.batch_size, "buffer_size must be at least batch_size"),
            (
                self.lr > 0 and self.target_update > 0 and self.updates_per_step > 0,
                "lr, target_update and updates_per_step must be positive",
            ),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"invalid training setting: {message}")
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def field_docs(cls: type) -> dict[str, str]:
    """The string literal that follows each field in the class body."""
    body = ast.parse(inspect.getsource(cls)).body[0].body
    docs = {}
    for statement, following in zip(body, body[1:], strict=False):
        if (
            isinstance(statement, ast.AnnAssign)
            and isinstance(following, ast.Expr)
            and isinstance(following.value, ast.Constant)
        ):
            docs[statement.target.id] = following.value.value
    return docs


def build_parser(cls: type = TrainConfig) -> argparse.ArgumentParser:
    """One flag per dataclass field, in both spellings, with the field's docstring as help."""
    parser = argparse.ArgumentParser(
        description="Train the two agents (Problem 2).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    docs = field_docs(cls)
    for spec in dataclasses.fields(cls):
        default = (
            spec.default_factory()
            if spec.default_factory is not dataclasses.MISSING
            else spec.default
        )
        names = [f"--{spec.name}"] + (
            [f"--{spec.name.replace('_', '-')}"] if "_" in spec.name else []
        )
        options: dict[str, Any] = {
            "dest": spec.name,
            "default": default,
            "help": docs.get(spec.name, ""),
        }
        if isinstance(default, bool):
            options["action"] = argparse.BooleanOptionalAction
        elif isinstance(default, list):
            options |= {"type": int, "nargs": "+"}
        else:
            options["type"] = type(default)
        parser.add_argument(*names, **options)
    return parser


def parse_config(argv: list[str] | None = None) -> TrainConfig:
    return TrainConfig(**vars(build_parser().parse_args(argv))).validate()
