"""Every setting of a training run, declared once: its default, its meaning and its allowed
range, in one field of :class:`TrainConfig`. ``train.py`` makes a flag of each field
(``--num_episodes`` or ``--num-episodes``, the help, the default); :func:`validated` checks
every field with the check it was declared with, then the relations between fields, and
raises :class:`SettingError` naming each bad field, its value and its allowed range before
any work starts. A check maps a value to None (allowed) or to the problem ("must be an
integer >= 1")."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import difflib
import inspect
import math
import os
import sys
import textwrap
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rollout import SELECT_BY
from vector_env import REWARD_MODES, generate_map, is_integer

TRAINABLE_MODES = ("independent", "comm", "distance", "full")  # models.MASKED_INPUTS' order
MODES = tuple(m for m in TRAINABLE_MODES if m != "distance")  # the assignment's: --mode all
MAX_SEED = 2**32 - 1
MAX_GRID_SIDE = 100
DEFAULT_OUTPUT_DIR = Path(__file__).resolve().parent / "results"
RUN_ONLY_FIELDS = ("output_dir", "workers", "overwrite")  # where and how, not what

Check = Callable[[Any], str | None]
Problem = tuple[str, str, Any]  # (field name, what is wrong, the value)


# ------------------------------------------------------------------ the checks
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


POSITIVE = number_in(0.0, math.inf, low_open=True, high_open=True)
NON_NEGATIVE = number_in(0.0, math.inf, high_open=True)
FRACTION = number_in(0.0, 1.0)


def one_of(*choices: str) -> Check:
    return lambda value: None if value in choices else f"must be one of {', '.join(choices)}"


def boolean(value: Any) -> str | None:
    return None if isinstance(value, bool) else "must be True or False"


def folder(value: Any) -> str | None:
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        return "must be a folder path"
    return "must be a folder, not a file" if Path(value).is_file() else None


def mode_list(value: Any) -> str | None:
    """``all`` or a comma-separated list of distinct trainable modes."""
    if value == "all":
        return None
    chosen = value.split(",") if isinstance(value, str) and value else []
    if chosen and set(chosen) <= set(TRAINABLE_MODES) and len(set(chosen)) == len(chosen):
        return None
    shown = ", ".join(TRAINABLE_MODES)
    return f"must be all or a comma-separated list of distinct modes from {shown}"


def distinct_seeds(value: Any) -> str | None:
    ok = (
        isinstance(value, (list, tuple))
        and all(is_integer(v) and 0 <= v <= MAX_SEED for v in value)
        and len(set(value)) == len(value)
    )
    return None if ok else f"must be distinct integers in 0..{MAX_SEED}"


def grid_sides(value: Any) -> str | None:
    """An integer in 3..MAX_GRID_SIDE, or a list of one or two (rows and columns)."""
    values = value if isinstance(value, list) else [value]
    ok = len(values) in (1, 2) and all(is_integer(v) and 3 <= v <= MAX_GRID_SIDE for v in values)
    return None if ok else f"must be one or two integers in 3..{MAX_GRID_SIDE}"


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


def setting(
    default: Any, check: Check, items: tuple[Callable[[str], Any], str] | None = None
) -> Any:
    """A dataclass field declared once: its default and its ``check`` (its help is the
    docstring under it, :func:`field_help`); ``items`` = (item type, metavar) makes its flag a
    list flag. A list default, or a function (e.g. the core count), is built anew for each
    config."""
    metadata = {"check": check, "items": items}
    if callable(default):
        return field(default_factory=default, metadata=metadata)
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=metadata)
    return field(default=default, metadata=metadata)


def field_help(cls: type) -> dict[str, str]:
    """Each field's help: the docstring written under it in ``cls`` or a base class."""
    helps: dict[str, str] = {}
    for klass in reversed(cls.__mro__[:-1]):
        body = ast.parse(textwrap.dedent(inspect.getsource(klass))).body[0].body
        for field_node, doc in zip(body, body[1:], strict=False):
            if isinstance(field_node, ast.AnnAssign) and isinstance(doc, ast.Expr):
                text = doc.value.value if isinstance(doc.value, ast.Constant) else ""
                helps[field_node.target.id] = " ".join(str(text).split())
    return helps


# ------------------------------------------------------------------ the settings
@dataclass
class TrainConfig:
    """The settings of a batch of runs: every (mode, seed) of ``run_modes()`` x
    ``run_seeds()`` on one map, in ``workers`` processes; one run reads them with its own
    ``mode`` and ``seed``."""

    mode: str = setting("all", mode_list, items=(str, "MODE"))
    """independent (patch), comm (+ message), full (+ distance), all (these three) or a list;
    distance (patch + distance) only when listed"""
    seed: int = setting(641, int_in(0, MAX_SEED))
    """first training seed (seed, seed + 1, ... unless --seeds is given)"""
    num_seeds: int = setting(10, int_in(1))
    """number of training seeds per mode (1 or more)"""
    seeds: list[int] = setting([], distinct_seeds, items=(int, "SEED"))
    """explicit distinct training seeds (override --seed and --num_seeds)"""
    map_seed: int = setting(641, int_in(0, MAX_SEED))
    """seed of the map (obstacles and target) every run trains on"""
    grid_size: int | list[int] = setting(10, grid_sides, items=(int, "N"))
    """grid side (--grid_size 10) or rows and columns (--grid_size 10 10)"""
    max_steps: int = setting(50, int_in(1))
    """episode time limit (a cut-off: the TD target bootstraps through it)"""
    reward_mode: str = setting("goal", one_of(*REWARD_MODES))
    """team reward learned from (vector_env.team_rewards): goal (+10 / -0.1), per_step (the
    assignment's +10 / +2 / -0.1) or arrival (+2 on an agent's first arrival)"""
    total_steps: int = setting(300_000, int_in(1))
    """env steps per run, summed over the parallel environments"""
    num_episodes: int = setting(0, int_in(0))
    """if > 0, train this many episodes instead of --total_steps"""
    num_envs: int = setting(64, int_in(1))
    """parallel environments that collect experience"""
    batch_size: int = setting(128, int_in(1))
    """transitions per gradient update"""
    lr: float = setting(5e-4, POSITIVE)
    """Adam learning rate at the start (finite, > 0)"""
    lr_end_factor: float = setting(0.03, FRACTION)
    """final learning rate, as a fraction of lr (linear decay)"""
    gamma: float = setting(0.99, number_in(0.0, 1.0, high_open=True))
    """discount factor, in [0, 1)"""
    n_step: int = setting(3, int_in(1))
    """rewards in each TD target (fewer where the episode ends first)"""
    epsilon_start: float = setting(1.0, FRACTION)
    """initial exploration rate, in [0, 1]"""
    epsilon_end: float = setting(0.05, FRACTION)
    """final exploration rate, in [0, epsilon_start]"""
    epsilon_decay: float = setting(0.0, decay_factor)
    """the skeleton's multiplicative factor in (0, 1): epsilon <- max(epsilon_end, epsilon *
    factor) after each finished episode; 0 = linear schedule"""
    epsilon_fraction: float = setting(0.3, number_in(0.0, 1.0, low_open=True))
    """with --epsilon_decay 0: fraction of the run over which epsilon falls linearly"""
    hidden_dim: int = setting(128, int_in(1))
    """units of the hidden layer"""
    target_update: int = setting(0, int_in(0))
    """gradient updates (not episodes, not env steps) between hard copies into the target networks;
    0 = a soft update at --target_tau"""
    target_tau: float = setting(0.005, number_in(0.0, 1.0, low_open=True))
    """with --target_update 0: fraction of the way to the online network each target network moves
    after every update"""
    buffer_size: int = setting(100_000, int_in(1))
    """replay capacity, joint transitions (>= batch_size)"""
    learning_starts: int = setting(5_000, int_in(0))
    """env steps before the first update (>= batch_size)"""
    updates_per_step: int = setting(2, int_in(1))
    """gradient updates per step of the parallel environments"""
    max_grad_norm: float = setting(10.0, POSITIVE)
    """gradient-norm clipping threshold (finite, > 0)"""
    advantage_learning: float = setting(0.95, number_in(0.0, 1.0, high_open=True))
    """alpha of advantage learning (Bellemare et al. 2016): the target minus alpha (max_b Q(s, b) -
    Q(s, a)) widens the action gaps; 0 = plain Double DQN"""
    advantage_learning_ramp: float = setting(0.3, number_in(0.0, 1.0, low_open=True))
    """fraction of the run for alpha to rise from 0"""
    comm_learning: str = setting("dial", one_of("dial", "none"))
    """dial: train the message head through the partner's TD loss; none: leave it untrained"""
    comm_noise: float = setting(1.0, NON_NEGATIVE)
    """std of the Gaussian noise on the message logit (DIAL)"""
    target_potential: float = setting(4.0, NON_NEGATIVE)
    """potential-based shaping seen by learning only (Ng et al. 1999): Phi per agent on the target,
    adding gamma Phi(s') - Phi(s); 0 = none"""
    potential_credit: str = setting("agent", one_of("agent", "team"))
    """whose arrivals the shaping pays each agent for: agent (its own; Devlin and Kudenko 2011) or
    team (both agents')"""
    eval_interval: int = setting(10_000, int_in(1))
    """env steps between periodic evaluations"""
    eval_episodes: int = setting(200, int_in(1))
    """episodes of each periodic evaluation (validation episodes)"""
    final_eval_episodes: int = setting(1000, int_in(1))
    """validation episodes of the final evaluation that picks the best seed per mode"""
    keep_best: bool = setting(True, boolean)
    """end with the weights that scored best in the evaluations"""
    select_by: str = setting("steps", one_of(*SELECT_BY))
    """what picks checkpoints and the best seed (greedy and epsilon = 0.05 means): steps (fewest
    steps within one point of the best success), success or return"""
    save_freq: int = setting(0, int_in(0))
    """environment steps between intermediate model saves (0: at the end only)"""
    output_dir: str = setting(str(DEFAULT_OUTPUT_DIR), folder)
    """folder for agent_models/ and training_logs/, relative to the current folder (default:
    problem2/results)"""
    workers: int = setting(available_cores, int_in(1))
    """parallel training processes (default: the available cores)"""
    overwrite: bool = setting(False, boolean)
    """replace a batch with other settings in --output_dir"""

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

    def identity(self) -> dict[str, Any]:
        """What a batch is, as its manifest records it (compared to decide replace vs refuse)."""
        return {
            "modes": self.run_modes(),
            "seeds": self.run_seeds(),
            "map_seed": self.map_seed,
            "reward_mode": self.reward_mode,
            "hyperparameters": self.hyperparameters(),
        }


# ------------------------------------------------------------------ validation
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


def validated(cfg: TrainConfig, whole_run: bool = True) -> TrainConfig:
    """``cfg`` if every field passes the check it was declared with (a study's subclass
    declares its own fields' checks the same way) and, for a ``whole_run`` of ``train()``, its
    budget reaches the first update; otherwise :class:`SettingError` listing every invalid
    field with its allowed range. A field without a check is a TypeError."""
    problems = []
    for spec in dataclasses.fields(cfg):
        if spec.metadata.get("check") is None:
            raise TypeError(f"no check for the setting {spec.name} of {type(cfg).__name__}")
        value = getattr(cfg, spec.name)
        problem = spec.metadata["check"](value)
        if problem:
            problems.append((spec.name, problem, value))
    problems += cross_field_problems(cfg, {name for name, _, _ in problems}, whole_run)
    if problems:
        raise SettingError(*problems[0], *problems[1:])
    return cfg


def cross_field_problems(
    cfg: TrainConfig, invalid: Collection[str] = (), whole_run: bool = True
) -> list[Problem]:
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
    if whole_run and readable(*BUDGET_FIELDS):
        problems += budget_problems(cfg)
    if readable("grid_size", "map_seed"):
        try:
            generate_map(cfg.grid_shape(), cfg.map_seed)
        except ValueError as error:
            problem = f"gives no usable map on this grid ({error})"
            problems.append(("map_seed", problem, cfg.map_seed))
    return problems


BUDGET_FIELDS = ("total_steps", "num_episodes", "num_envs", "learning_starts", "max_steps")


def budget_problems(cfg: TrainConfig) -> list[Problem]:
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
    """Raise :class:`SettingError` if ``value`` fails TrainConfig field ``name``'s check
    (checked alone, e.g. for a study's flag that is turned into other fields)."""
    spec = next(s for s in dataclasses.fields(TrainConfig) if s.name == name)
    check_value(name, value, spec.metadata["check"])


# ------------------------------------------------------------------ the command line
class ListAction(argparse.Action):
    """A list flag: values space- or comma-separated, each converted by ``item_type``."""

    def __init__(self, *args: Any, item_type: Callable[[str], Any] = str, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.item_type = item_type

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: ANN001
        items = []
        for token in values if isinstance(values, list) else [values]:
            for part in token.split(","):
                if not part.strip():
                    raise argparse.ArgumentError(self, f"empty item in {token!r}")
                try:
                    items.append(self.item_type(part.strip()))
                except ValueError:
                    name = getattr(self.item_type, "__name__", "value")
                    raise argparse.ArgumentError(self, f"invalid {name} value: {part!r}") from None
        setattr(namespace, self.dest, items)


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are a line each, naming the flag and the fix, with
    "did you mean" for a misspelt flag, instead of the whole usage block."""

    def error(self, message: str) -> None:  # type: ignore[override]
        if message.startswith("unrecognized arguments: "):
            known = [o for action in self._actions for o in action.option_strings]
            for word in message.split(": ", 1)[1].split():
                close = difflib.get_close_matches(word.split("=")[0], known, n=1, cutoff=0.6)
                if close:
                    message += f" (did you mean {close[0]}?)"
        sys.stderr.write(f"{self.prog}: error: {message}\n(see {self.prog} --help)\n")
        sys.exit(2)


def build_parser(cls: type = TrainConfig, **parser_options: Any) -> OneLineParser:
    """One flag per dataclass field, in both spellings, with the field's help and default."""
    parser = OneLineParser(allow_abbrev=False, **parser_options)
    helps = field_help(cls)
    for spec in dataclasses.fields(cls):
        factory = spec.default_factory
        default = spec.default if factory is dataclasses.MISSING else factory()
        names = list(dict.fromkeys([f"--{spec.name}", f"--{spec.name.replace('_', '-')}"]))
        options: dict[str, Any] = {"dest": spec.name, "default": default}
        # A default that is a path of this machine or the core count: its help names it.
        shown_default = "" if "(default:" in helps[spec.name] else " (default: %(default)s)"
        options["help"] = helps[spec.name] + shown_default
        if isinstance(default, bool):
            options["action"] = argparse.BooleanOptionalAction
        elif spec.metadata["items"]:
            item_type, options["metavar"] = spec.metadata["items"]
            options |= {"nargs": "+", "action": ListAction, "item_type": item_type}
        else:
            options["type"] = type(default)
        parser.add_argument(*names, **options)
    return parser


def parse_config(
    argv: list[str] | None = None, parser: argparse.ArgumentParser | None = None
) -> TrainConfig:
    """Parse and validate; a bad value raises :class:`SettingError` (a ValueError) naming,
    for each bad setting, the flag, the value and the allowed range."""
    values = vars((parser or build_parser()).parse_args(argv))
    if isinstance(values.get("mode"), list):
        values["mode"] = ",".join(values["mode"])
    return validated(TrainConfig(**values))
