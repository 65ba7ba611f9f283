"""Hyperparameters of Problem 2's training, one dataclass field each, declared once with its
default and help. ``TrainConfig`` is what one run reads; ``settings.BatchConfig`` adds a
batch's fields and ``settings.RULES`` the range of every field; ``train.py`` makes one flag
per field (``--num_episodes`` or ``--num-episodes``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

TRAINABLE_MODES = ("independent", "comm", "distance", "full")  # distance: the map panel's 2 x 2
DEFAULT_OUTPUT_DIR = Path(__file__).resolve().parent / "results"


def setting(default: Any, help: str, items: tuple[Callable[[str], Any], str] | None = None) -> Any:
    """A dataclass field declared once: its default and one-line ``help``; ``items`` = (item
    type, metavar) makes its flag a list flag. A list default, or a function (e.g. the core
    count), is built anew for each config."""
    metadata = {"help": help, "items": items}
    if callable(default):
        return field(default_factory=default, metadata=metadata)
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass
class TrainConfig:
    """What one training run reads (one mode, one seed; ``mode`` and ``seed`` also name the
    first of a batch's, ``settings.BatchConfig``)."""

    mode: str = setting(
        "all",
        "independent (patch), comm (+ message), full (+ distance), all (these three) or a list; "
        "distance (patch + distance) only when listed",
        items=(str, "MODE"),
    )
    seed: int = setting(641, "first training seed (seed, seed + 1, ... unless --seeds is given)")
    reward_mode: str = setting(
        "goal",
        "team reward learned from (vector_env.team_rewards): goal (+10 / -0.1), per_step "
        "(the assignment's +10 / +2 / -0.1) or arrival (+2 on an agent's first arrival)",
    )
    total_steps: int = setting(300_000, "env steps per run, summed over the parallel environments")
    num_episodes: int = setting(0, "if > 0, train this many episodes instead of --total_steps")
    num_envs: int = setting(64, "parallel environments that collect experience")
    batch_size: int = setting(128, "transitions per gradient update")
    lr: float = setting(5e-4, "Adam learning rate at the start (finite, > 0)")
    lr_end_factor: float = setting(0.03, "final learning rate, as a fraction of lr (linear decay)")
    gamma: float = setting(0.99, "discount factor, in [0, 1)")
    n_step: int = setting(3, "rewards in each TD target (fewer where the episode ends first)")
    epsilon_start: float = setting(1.0, "initial exploration rate, in [0, 1]")
    epsilon_end: float = setting(0.05, "final exploration rate, in [0, epsilon_start]")
    epsilon_decay: float = setting(
        0.0,
        "the skeleton's multiplicative factor in (0, 1): epsilon <- max(epsilon_end, epsilon * "
        "factor) after each finished episode; 0 = linear schedule",
    )
    epsilon_fraction: float = setting(
        0.3, "with --epsilon_decay 0: fraction of the run over which epsilon falls linearly"
    )
    hidden_dim: int = setting(128, "units of the hidden layer")
    target_update: int = setting(
        0,
        "gradient updates (not episodes, not env steps) between hard copies into the target "
        "networks; 0 = a soft update at --target_tau",
    )
    target_tau: float = setting(
        0.005,
        "with --target_update 0: fraction of the way to the online network each target "
        "network moves after every update",
    )
    buffer_size: int = setting(100_000, "replay capacity, joint transitions (>= batch_size)")
    learning_starts: int = setting(5_000, "env steps before the first update (>= batch_size)")
    updates_per_step: int = setting(2, "gradient updates per step of the parallel environments")
    max_grad_norm: float = setting(10.0, "gradient-norm clipping threshold (finite, > 0)")
    advantage_learning: float = setting(
        0.95,
        "alpha of advantage learning (Bellemare et al. 2016): the target minus alpha (max_b "
        "Q(s, b) - Q(s, a)) widens the action gaps; 0 = plain Double DQN",
    )
    advantage_learning_ramp: float = setting(0.3, "fraction of the run for alpha to rise from 0")
    comm_learning: str = setting(
        "dial",
        "dial: train the message head through the partner's TD loss; none: leave it untrained",
    )
    comm_noise: float = setting(1.0, "std of the Gaussian noise on the message logit (DIAL)")
    eval_interval: int = setting(10_000, "env steps between periodic evaluations")
    eval_episodes: int = setting(200, "episodes of each periodic evaluation (validation episodes)")
    keep_best: bool = setting(True, "end with the weights that scored best in the evaluations")
    select_by: str = setting(
        "steps",
        "what picks checkpoints and the best seed (greedy and epsilon = 0.05 means): steps "
        "(fewest steps within one point of the best success), success or return",
    )
    output_dir: str = setting(
        str(DEFAULT_OUTPUT_DIR),
        "folder for agent_models/ and training_logs/, relative to the current folder "
        "(default: problem2/results)",
    )

    # ------------------------------------------------ the reward only learning sees
    target_potential: float = setting(
        4.0,
        "potential-based shaping seen by learning only (Ng et al. 1999): Phi per agent on the "
        "target, adding gamma Phi(s') - Phi(s); 0 = none",
    )
    potential_credit: str = setting(
        "agent",
        "whose arrivals the shaping pays each agent for: agent (its own; Devlin and Kudenko "
        "2011) or team (both agents')",
    )
