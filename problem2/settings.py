"""The settings of a batch of training runs and the rule of every setting, checked before any
work starts. :class:`BatchConfig` is ``train_config.TrainConfig`` (what one run reads) with
the batch's modes, seeds, map and processes: ``python train.py`` takes one, a flag per field.
``RULES`` gives each field its allowed range; a check maps a value to None (allowed) or to
the problem, phrased with the allowed range ("must be an integer >= 1"); :func:`validated`
raises :class:`SettingError` with every problem found, each naming its field (the flag
``--name``). The command line, the batch and the studies call it; the trainer takes a
checked config."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from typing import Any

from grid_maps import generate_map, is_integer
from rollout import SELECT_BY
from train_config import TRAINABLE_MODES, TrainConfig, setting

MODES = ("independent", "comm", "full")  # the assignment's ablation: --mode all
MAX_SEED = 2**32 - 1
MAX_GRID_SIDE = 100
RUN_ONLY_FIELDS = ("output_dir", "workers", "overwrite")  # where and how, not what

Check = Callable[[Any], str | None]
Problem = tuple[str, str, Any]  # (field name, what is wrong, the value)


class SettingError(ValueError):
    """Invalid training settings: ``problems`` lists (name, problem, value) for each, the
    flag being ``--name``; ``name``, ``problem`` and ``value`` are the first one's."""

    def __init__(self, name: str, problem: str, value: Any, *more: Problem) -> None:
        self.problems: list[Problem] = [(name, problem, value), *more]
        super().__init__("\n".join(f"{n} {p}, got {v!r}" for n, p, v in self.problems))
        self.name, self.problem, self.value = name, problem, value

    def __reduce__(self) -> tuple:
        # Rebuilt from its problems: a worker process's error then reaches the parent (the
        # default pickling passes only the message, and the pool's result thread dies on it).
        return type(self), (*self.problems[0], *self.problems[1:])


def usage(error: SettingError) -> str:
    """The usage error, a line per problem: ``argument --name: problem, got value``."""
    return "\n".join(
        f"argument --{name}: {problem}, got {shown_value(value)}"
        for name, problem, value in error.problems
    )


def shown_value(value: Any) -> str:
    """A value as typed on the command line (a list space-separated, a string quoted)."""
    if isinstance(value, list):
        return " ".join(str(v) for v in value)
    return repr(value) if isinstance(value, str) else str(value)


def check_value(name: str, value: Any, check: Check) -> None:
    """Raise :class:`SettingError` if ``check`` finds a problem with ``value``."""
    problem = check(value)
    if problem:
        raise SettingError(name, problem, value)


def int_in(low: int, high: int | None = None) -> Check:
    allowed = f"an integer >= {low}" if high is None else f"an integer in {low}..{high}"

    def check(value: Any) -> str | None:
        ok = is_integer(value) and value >= low and (high is None or value <= high)
        return None if ok else f"must be {allowed}"

    return check


def number_in(low: float, high: float, low_open: bool = False, high_open: bool = False) -> Check:
    left, right = "(" if low_open else "[", ")" if high_open else "]"
    shown_high = "inf)" if math.isinf(high) else f"{high:g}{right}"
    allowed = f"a finite number in {left}{low:g}, {shown_high}"

    def check(value: Any) -> str | None:
        ok = (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and math.isfinite(value)
            and (value > low if low_open else value >= low)
            and (value < high if high_open else value <= high)
        )
        return None if ok else f"must be {allowed}"

    return check


def one_of(*choices: str) -> Check:
    return lambda value: None if value in choices else f"must be one of {', '.join(choices)}"


def boolean(value: Any) -> str | None:
    return None if isinstance(value, bool) else "must be True or False"


def folder(value: Any) -> str | None:
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        return "must be a folder path"
    return "must be a folder, not a file" if Path(value).is_file() else None


def mode_list(modes: Sequence[str]) -> Check:
    """``all`` or a comma-separated list of distinct ``modes``."""
    shown = ", ".join(modes)

    def check(value: Any) -> str | None:
        if value == "all":
            return None
        chosen = value.split(",") if isinstance(value, str) and value else []
        if chosen and set(chosen) <= set(modes) and len(set(chosen)) == len(chosen):
            return None
        return f"must be all or a comma-separated list of distinct modes from {shown}"

    return check


def distinct_ints(low: int, high: int) -> Check:
    """A list (or tuple) of distinct integers in low..high."""

    def check(value: Any) -> str | None:
        ok = (
            isinstance(value, (list, tuple))
            and all(is_integer(v) and low <= v <= high for v in value)
            and len(set(value)) == len(value)
        )
        return None if ok else f"must be distinct integers in {low}..{high}"

    return check


def one_or_two_ints(low: int, high: int) -> Check:
    """An integer in low..high, or a list of one or two (e.g. a grid's rows and columns)."""

    def check(value: Any) -> str | None:
        values = value if isinstance(value, list) else [value]
        ok = len(values) in (1, 2) and all(is_integer(v) and low <= v <= high for v in values)
        return None if ok else f"must be one or two integers in {low}..{high}"

    return check


def available_cores() -> int:
    """Cores this process may run on (the affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


@dataclasses.dataclass
class BatchConfig(TrainConfig):
    """A batch of runs: every (mode, seed) of ``run_modes()`` x ``run_seeds()`` on one map,
    trained in ``workers`` processes; each run reads the :class:`TrainConfig` fields."""

    num_seeds: int = setting(10, "number of training seeds per mode (1 or more)")
    seeds: list[int] = setting(
        [],
        "explicit distinct training seeds (override --seed and --num_seeds)",
        items=(int, "SEED"),
    )
    map_seed: int = setting(
        641,
        "seed of the map (obstacles and target) every run trains on",
    )
    grid_size: int | list[int] = setting(
        10,
        "grid side (--grid_size 10) or rows and columns (--grid_size 10 10)",
        items=(int, "N"),
    )
    max_steps: int = setting(
        50,
        "episode time limit (a cut-off: the TD target bootstraps through it)",
    )
    final_eval_episodes: int = setting(
        1000,
        "validation episodes of the final evaluation that picks the best seed per mode",
    )
    save_freq: int = setting(
        0,
        "environment steps between intermediate model saves (0: at the end only)",
    )
    workers: int = setting(
        available_cores,
        "parallel training processes (default: the available cores)",
    )
    overwrite: bool = setting(
        False,
        "replace a batch with other settings in --output_dir",
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

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def hyperparameters(self) -> dict[str, Any]:
        """Every field that shapes the results (not where they go or how many processes)."""
        return {k: v for k, v in self.to_dict().items() if k not in RUN_ONLY_FIELDS}


def decay_factor(value: Any) -> str | None:
    """0 (the linear schedule) or the skeleton's multiplicative factor in (0, 1)."""
    zero = value == 0 and not isinstance(value, bool)
    if zero or number_in(0.0, 1.0, low_open=True, high_open=True)(value) is None:
        return None
    return (
        "must be 0 (linear schedule) or a multiplicative factor per episode in (0, 1), e.g. 0.995"
    )


RULES: dict[str, Check] = {  # every field of BatchConfig, in its order
    "mode": mode_list(TRAINABLE_MODES),
    "seed": int_in(0, MAX_SEED),
    "reward_mode": one_of("goal", "per_step", "arrival"),
    "total_steps": int_in(1),
    "num_episodes": int_in(0),
    "num_envs": int_in(1),
    "batch_size": int_in(1),
    "lr": number_in(0.0, math.inf, low_open=True, high_open=True),
    "lr_end_factor": number_in(0.0, 1.0),
    "gamma": number_in(0.0, 1.0, high_open=True),
    "n_step": int_in(1),
    "epsilon_start": number_in(0.0, 1.0),
    "epsilon_end": number_in(0.0, 1.0),
    "epsilon_decay": decay_factor,
    "epsilon_fraction": number_in(0.0, 1.0, low_open=True),
    "hidden_dim": int_in(1),
    "target_update": int_in(0),
    "target_tau": number_in(0.0, 1.0, low_open=True),
    "buffer_size": int_in(1),
    "learning_starts": int_in(0),
    "updates_per_step": int_in(1),
    "max_grad_norm": number_in(0.0, math.inf, low_open=True, high_open=True),
    "advantage_learning": number_in(0.0, 1.0, high_open=True),
    "advantage_learning_ramp": number_in(0.0, 1.0, low_open=True),
    "comm_learning": one_of("dial", "none"),
    "comm_noise": number_in(0.0, math.inf, high_open=True),
    "eval_interval": int_in(1),
    "eval_episodes": int_in(1),
    "keep_best": boolean,
    "select_by": one_of(*SELECT_BY),
    "output_dir": folder,
    "target_potential": number_in(0.0, math.inf, high_open=True),
    "potential_credit": one_of("agent", "team"),
    "num_seeds": int_in(1),
    "seeds": distinct_ints(0, MAX_SEED),
    "map_seed": int_in(0, MAX_SEED),
    "grid_size": one_or_two_ints(3, MAX_GRID_SIDE),
    "max_steps": int_in(1),
    "final_eval_episodes": int_in(1),
    "save_freq": int_in(0),
    "workers": int_in(1),
    "overwrite": boolean,
}


def validated(cfg: TrainConfig, rules: dict[str, Check] = RULES) -> TrainConfig:
    """``cfg`` if every field keeps its rule in ``rules`` (a subclass passes its own, e.g.
    ``studies.pool_training.POOL_RULES``); otherwise :class:`SettingError` listing every
    invalid field with its allowed range. A field without a rule is a TypeError."""
    problems = []
    for spec in dataclasses.fields(cfg):
        if spec.name not in rules:
            raise TypeError(f"no rule for the setting {spec.name} of {type(cfg).__name__}")
        value = getattr(cfg, spec.name)
        problem = rules[spec.name](value)
        if problem:
            problems.append((spec.name, problem, value))
    problems += cross_field_problems(cfg, invalid={name for name, _, _ in problems})
    if problems:
        raise SettingError(*problems[0], *problems[1:])
    return cfg


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
    if isinstance(cfg, BatchConfig) and readable(*BUDGET_FIELDS):
        problems += budget_problems(cfg)
    if isinstance(cfg, BatchConfig) and readable("grid_size", "map_seed"):
        try:
            generate_map(cfg.grid_shape(), cfg.map_seed)
        except ValueError as error:
            problem = f"gives no usable map on this grid ({error})"
            problems.append(("map_seed", problem, cfg.map_seed))
    return problems


BUDGET_FIELDS = ("total_steps", "num_episodes", "num_envs", "learning_starts", "max_steps")


def budget_problems(cfg: BatchConfig) -> list[Problem]:
    """A budget that ends before the first gradient update (``learning_starts`` env steps)
    trains nothing: the run would report an untrained agent. With ``num_episodes`` the most
    env steps a run can take is ``num_envs`` x ``max_steps`` per ``num_envs`` episodes."""
    first_update = f"learning_starts {cfg.learning_starts} (env steps before the first update)"
    if cfg.num_episodes == 0 and cfg.total_steps < cfg.learning_starts:
        problem = (
            f"must be at least {first_update}, or the run makes no update: raise "
            "--total_steps or lower --learning_starts"
        )
        return [("total_steps", problem, cfg.total_steps)]
    rounds = -(-cfg.num_episodes // cfg.num_envs)  # every copy ends an episode per round
    most_steps = rounds * cfg.num_envs * cfg.max_steps
    if cfg.num_episodes > 0 and most_steps < cfg.learning_starts:
        needed = (-(-cfg.learning_starts // (cfg.num_envs * cfg.max_steps)) - 1) * cfg.num_envs
        problem = (
            f"ends within {most_steps} env steps ({cfg.num_envs} environments, episodes of at "
            f"most {cfg.max_steps} steps), before {first_update}, so the run makes no update: "
            f"use at least {needed + 1} episodes or lower --learning_starts"
        )
        return [("num_episodes", problem, cfg.num_episodes)]
    return []


def check_setting(name: str, value: Any) -> None:
    """Raise :class:`SettingError` if ``value`` breaks BatchConfig field ``name``'s rule
    (checked alone, e.g. for a study's flag that is turned into other fields)."""
    check_value(name, value, RULES[name])
