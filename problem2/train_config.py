"""Hyperparameters of Problem 2's training, in one dataclass: each field is declared once by
``settings.setting`` (default, help, allowed range), every value is checked before any work
starts, and ``batch/plumbing.py`` builds one flag per field (``--num_episodes`` or
``--num-episodes``). Study extensions add fields in a subclass (``studies/pool_training.py``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from grid_maps import generate_map
from rollout import SELECT_BY
from settings import (
    Problem,
    SettingError,
    boolean,
    check_value,
    distinct_ints,
    folder,
    int_in,
    mode_list,
    number_in,
    one_of,
    one_or_two_ints,
    setting,
)

MODES = ("independent", "comm", "full")  # the assignment's ablation: --mode all
TRAINABLE_MODES = ("independent", "comm", "distance", "full")  # distance: the map panel's 2 x 2
DEFAULT_OUTPUT_DIR = Path(__file__).resolve().parent / "results"
MAX_SEED = 2**32 - 1
MAX_GRID_SIDE = 100
RUN_ONLY_FIELDS = ("output_dir", "workers", "overwrite")  # where and how, not what


def decay_factor(value: Any) -> str | None:
    """0 (the linear schedule) or the skeleton's multiplicative factor in (0, 1)."""
    zero = value == 0 and not isinstance(value, bool)
    if zero or number_in(0.0, 1.0, low_open=True, high_open=True)(value) is None:
        return None
    return (
        "must be 0 (linear schedule) or a multiplicative factor per episode in (0, 1), e.g. 0.995"
    )


def available_cores() -> int:
    """Cores this process may run on (the affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


@dataclass
class TrainConfig:
    """Everything that defines a training run (one mode, one seed) or a batch of them."""

    mode: str = setting(
        "all",
        "independent (patch), comm (+ message), full (+ distance), all (these three) or a list; "
        "distance (patch + distance) only when listed",
        mode_list(TRAINABLE_MODES),
        items=(str, "MODE"),
    )
    seed: int = setting(
        641,
        "first training seed (seed, seed + 1, ... unless --seeds is given)",
        int_in(0, MAX_SEED),
    )
    num_seeds: int = setting(10, "number of training seeds per mode (1 or more)", int_in(1))
    seeds: list[int] = setting(
        [],
        "explicit distinct training seeds (override --seed and --num_seeds)",
        distinct_ints(0, MAX_SEED),
        items=(int, "SEED"),
    )
    map_seed: int = setting(
        641,
        "seed of the map (obstacles and target) every run trains on",
        int_in(0, MAX_SEED),
    )
    grid_size: int | list[int] = setting(
        10,
        "grid side (--grid_size 10) or rows and columns (--grid_size 10 10)",
        one_or_two_ints(3, MAX_GRID_SIDE),
        items=(int, "N"),
    )
    max_steps: int = setting(
        50,
        "episode time limit (a cut-off: the TD target bootstraps through it)",
        int_in(1),
    )
    reward_mode: str = setting(
        "goal",
        "team reward learned from (vector_env.team_rewards): goal (+10 / -0.1), per_step "
        "(the assignment's +10 / +2 / -0.1) or arrival (+2 on an agent's first arrival)",
        one_of("goal", "per_step", "arrival"),
    )
    total_steps: int = setting(
        300_000,
        "environment steps per run, summed over the parallel environments",
        int_in(1),
    )
    num_episodes: int = setting(
        0, "if positive, train for this many finished episodes instead of --total_steps", int_in(0)
    )
    num_envs: int = setting(64, "parallel environments that collect experience", int_in(1))
    batch_size: int = setting(128, "transitions per gradient update", int_in(1))
    lr: float = setting(
        5e-4,
        "Adam learning rate at the start (finite, > 0)",
        number_in(0.0, math.inf, low_open=True, high_open=True),
    )
    lr_end_factor: float = setting(
        0.03,
        "final learning rate as a fraction of lr, reached linearly at the end",
        number_in(0.0, 1.0),
    )
    gamma: float = setting(0.99, "discount factor, in [0, 1)", number_in(0.0, 1.0, high_open=True))
    n_step: int = setting(
        3,
        "steps of reward in each TD target (fewer where the episode ends first)",
        int_in(1),
    )
    epsilon_start: float = setting(1.0, "initial exploration rate, in [0, 1]", number_in(0.0, 1.0))
    epsilon_end: float = setting(
        0.05, "final exploration rate, in [0, epsilon_start]", number_in(0.0, 1.0)
    )
    epsilon_decay: float = setting(
        0.0,
        "the skeleton's multiplicative factor in (0, 1): epsilon <- max(epsilon_end, epsilon * "
        "factor) after each finished episode; 0 = linear schedule",
        decay_factor,
    )
    epsilon_fraction: float = setting(
        0.3,
        "with --epsilon_decay 0: fraction of the run over which epsilon falls linearly",
        number_in(0.0, 1.0, low_open=True),
    )
    hidden_dim: int = setting(128, "units of the hidden layer", int_in(1))
    target_update: int = setting(
        0,
        "gradient updates (not episodes, not env steps) between hard copies into the target "
        "networks; 0 = a soft update at --target_tau",
        int_in(0),
    )
    target_tau: float = setting(
        0.005,
        "with --target_update 0: fraction of the way to the online network each target "
        "network moves after every update",
        number_in(0.0, 1.0, low_open=True),
    )
    buffer_size: int = setting(
        100_000, "replay capacity in joint transitions (at least batch_size)", int_in(1)
    )
    learning_starts: int = setting(
        5_000,
        "env steps collected before the first update (at least batch_size)",
        int_in(0),
    )
    updates_per_step: int = setting(
        2, "gradient updates per step of the parallel environments", int_in(1)
    )
    max_grad_norm: float = setting(
        10.0,
        "gradient-norm clipping threshold (finite, > 0)",
        number_in(0.0, math.inf, low_open=True, high_open=True),
    )
    advantage_learning: float = setting(
        0.95,
        "alpha of advantage learning (Bellemare et al. 2016): the target minus alpha (max_b "
        "Q(s, b) - Q(s, a)) widens the action gaps; 0 = plain Double DQN",
        number_in(0.0, 1.0, high_open=True),
    )
    advantage_learning_ramp: float = setting(
        0.3,
        "fraction of the run over which alpha rises linearly from 0",
        number_in(0.0, 1.0, low_open=True),
    )
    comm_learning: str = setting(
        "dial",
        "dial: train the message head through the partner's TD loss; none: leave it untrained",
        one_of("dial", "none"),
    )
    comm_noise: float = setting(
        1.0,
        "standard deviation of the Gaussian noise on the message logit (DIAL)",
        number_in(0.0, math.inf, high_open=True),
    )
    eval_interval: int = setting(
        10_000,
        "environment steps between evaluations on the validation episodes",
        int_in(1),
    )
    eval_episodes: int = setting(
        200, "episodes of each periodic evaluation (validation episodes)", int_in(1)
    )
    keep_best: bool = setting(
        True,
        "end with the weights that scored best in the periodic evaluations",
        boolean,
    )
    select_by: str = setting(
        "steps",
        "what picks checkpoints and the best seed (greedy and epsilon = 0.05 means): steps "
        "(fewest steps within one point of the best success), success or return",
        one_of(*SELECT_BY),
    )
    final_eval_episodes: int = setting(
        1000,
        "validation episodes of the final evaluation that picks the best seed per mode",
        int_in(1),
    )
    save_freq: int = setting(
        0,
        "environment steps between intermediate model saves (0: at the end only)",
        int_in(0),
    )
    output_dir: str = setting(
        str(DEFAULT_OUTPUT_DIR),
        "folder for agent_models/ and training_logs/, relative to the current folder "
        "(default: problem2/results)",
        folder,
    )
    workers: int = setting(
        available_cores,
        "parallel training processes (default: the available cores)",
        int_in(1),
    )
    overwrite: bool = setting(
        False,
        "replace a batch with other settings in --output_dir",
        boolean,
    )

    # ------------------------------------------------ the reward only learning sees
    target_potential: float = setting(
        4.0,
        "potential-based shaping seen by learning only (Ng et al. 1999): Phi per agent on the "
        "target, adding gamma Phi(s') - Phi(s); 0 = none",
        number_in(0.0, math.inf, high_open=True),
    )
    potential_credit: str = setting(
        "agent",
        "whose arrivals the shaping pays each agent for: agent (its own; Devlin and Kudenko "
        "2011) or team (both agents')",
        one_of("agent", "team"),
    )

    def __post_init__(self) -> None:
        # --grid_size 10 and --grid_size 10 10 (the skeleton's list) mean the same grid.
        if isinstance(self.grid_size, (list, tuple)):
            sides = list(self.grid_size)
            if len(sides) == 1 or (len(sides) == 2 and sides[0] == sides[1]):
                self.grid_size = sides[0]
            else:
                self.grid_size = sides

    def grid_shape(self) -> tuple[int, int]:
        """(rows, cols) of the grid."""
        if isinstance(self.grid_size, list):
            return int(self.grid_size[0]), int(self.grid_size[1])
        return int(self.grid_size), int(self.grid_size)

    def run_seeds(self) -> list[int]:
        return list(self.seeds) if self.seeds else [self.seed + i for i in range(self.num_seeds)]

    def run_modes(self) -> list[str]:
        return list(MODES) if self.mode == "all" else self.mode.split(",")

    def validate(self) -> TrainConfig:
        """Raise :class:`SettingError` listing every invalid field with its allowed range;
        return self."""
        problems = []
        for spec in dataclasses.fields(self):
            value = getattr(self, spec.name)
            problem = spec.metadata["check"](value)
            if problem:
                problems.append((spec.name, problem, value))
        problems += cross_field_problems(self, invalid={name for name, _, _ in problems})
        if problems:
            raise SettingError(*problems[0], *problems[1:])
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def hyperparameters(self) -> dict[str, Any]:
        """Every field that shapes the results (not where they go or how many processes)."""
        return {k: v for k, v in self.to_dict().items() if k not in RUN_ONLY_FIELDS}


def cross_field_problems(cfg: TrainConfig, invalid: Collection[str] = ()) -> list[Problem]:
    """Settings that are each valid but break training together, as (name, problem, value);
    relations that read a field named in ``invalid`` are not checked."""
    problems = []

    def readable(*names: str) -> bool:
        return not set(names).intersection(invalid)

    if readable("epsilon_start", "epsilon_end") and cfg.epsilon_end > cfg.epsilon_start:
        problem = f"must not exceed epsilon_start {cfg.epsilon_start}"
        problems.append(("epsilon_end", problem, cfg.epsilon_end))
    for name in ("buffer_size", "learning_starts"):
        if readable(name, "batch_size") and getattr(cfg, name) < cfg.batch_size:
            problem = f"must be at least batch_size {cfg.batch_size}"
            problems.append((name, problem, getattr(cfg, name)))
    if readable("grid_size", "map_seed"):
        try:
            generate_map(cfg.grid_shape(), cfg.map_seed)
        except ValueError as error:
            problem = f"gives no usable map on this grid ({error})"
            problems.append(("map_seed", problem, cfg.map_seed))
    return problems


def check_setting(name: str, value: Any) -> None:
    """Raise :class:`SettingError` if ``value`` breaks TrainConfig field ``name``'s rule
    (checked alone, e.g. for a study's flag that is turned into other fields)."""
    check_value(name, value, TrainConfig.__dataclass_fields__[name].metadata["check"])
