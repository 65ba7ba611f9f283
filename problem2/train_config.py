"""Hyperparameters of Problem 2's training, in one dataclass that also builds the CLI: a flag
per field (``--num_episodes`` or ``--num-episodes``; list flags take ``--seeds 641 642`` or
``--seeds 641,642``), its docstring the help text, every value checked before any work starts.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from grid_maps import MAX_POOL_SIZE, generate_map
from rollout import SELECT_BY

MODES = ("independent", "comm", "full")  # the assignment's ablation: --mode all
TRAINABLE_MODES = ("independent", "comm", "distance", "full")  # distance: the map panel's 2 x 2
DEFAULT_OUTPUT_DIR = Path(__file__).resolve().parent / "results"
MAX_SEED = 2**32 - 1
MAX_GRID_SIDE = 100
RUN_ONLY_FIELDS = ("output_dir", "workers", "overwrite")  # where and how, not what

# ------------------------------------------------------------ checks of single settings
Check = Callable[[Any], str | None]


class SettingError(ValueError):
    """An invalid training setting; ``name`` is the field (the flag is ``--name``)."""

    def __init__(self, name: str, problem: str, value: Any) -> None:
        super().__init__(f"{name} {problem}, got {value!r}")
        self.name, self.problem, self.value = name, problem, value

    def usage(self) -> str:
        """The usage error: ``argument --name: problem, got value``."""
        shown = repr(self.value) if isinstance(self.value, str) else str(self.value)
        if isinstance(self.value, list):
            shown = " ".join(str(v) for v in self.value)
        return f"argument --{self.name}: {self.problem}, got {shown}"


def check_value(name: str, value: Any, check: Check) -> None:
    """Raise :class:`SettingError` if ``check`` finds a problem with ``value``."""
    problem = check(value)
    if problem:
        raise SettingError(name, problem, value)


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def int_in(low: int, high: int | None = None) -> Check:
    allowed = f"an integer >= {low}" if high is None else f"an integer in {low}..{high}"

    def check(value: Any) -> str | None:
        ok = is_int(value) and value >= low and (high is None or value <= high)
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


def mode_list(value: Any) -> str | None:
    """``all`` or a comma-separated list of distinct modes."""
    if value == "all":
        return None
    chosen = value.split(",") if isinstance(value, str) and value else []
    if chosen and set(chosen) <= set(TRAINABLE_MODES) and len(set(chosen)) == len(chosen):
        return None
    modes = ", ".join(TRAINABLE_MODES)
    return f"must be all or a comma-separated list of distinct modes from {modes}"


def seed_list(value: Any) -> str | None:
    ok = (
        isinstance(value, (list, tuple))
        and all(is_int(s) and 0 <= s <= MAX_SEED for s in value)
        and len(set(value)) == len(value)
    )
    return None if ok else f"must be distinct integers in 0..{MAX_SEED}"


def grid_sides(value: Any) -> str | None:
    """One side (a square grid) or two, rows and columns."""
    sides = value if isinstance(value, list) else [value]
    ok = len(sides) in (1, 2) and all(is_int(s) and 3 <= s <= MAX_GRID_SIDE for s in sides)
    return None if ok else f"must be one or two integers in 3..{MAX_GRID_SIDE}"


def epsilon_decay(value: Any) -> str | None:
    zero = value == 0 and not isinstance(value, bool)
    if zero or number_in(0.0, 1.0, low_open=True, high_open=True)(value) is None:
        return None
    return (
        "must be 0 (linear schedule) or a multiplicative factor per episode in (0, 1), e.g. 0.995"
    )


def folder(value: Any) -> str | None:
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        return "must be a folder path"
    return "must be a folder, not a file" if Path(value).is_file() else None


def available_cores() -> int:
    """Cores this process may run on (the affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


@dataclass
class TrainConfig:
    """Everything that defines a training run (one mode, one seed) or a batch of them."""

    mode: str = "all"
    """independent (patch only), comm (+ message), full (+ distance), all (these three), or a
    list: comm full; distance (patch + distance, no message) only when listed"""
    seed: int = 641
    """first training seed; runs use seed, seed + 1, ... unless --seeds is given"""
    num_seeds: int = 10
    """number of training seeds per mode (1 or more)"""
    seeds: list[int] = field(default_factory=list)
    """explicit training seeds, distinct, 0..2^32-1 (overrides --seed and --num_seeds)"""
    map_seed: int = 641
    """seed (0..2^32-1) of the map (obstacles and target) that every run trains on"""
    grid_size: int | list[int] = 10
    """grid side (--grid_size 10) or rows and columns (--grid_size 10 10), each 3..100"""
    max_steps: int = 50
    """episode time limit (a cut-off, not a terminal state: the TD target bootstraps through it)"""
    reward_mode: str = "goal"
    """reward learned from (vector_env.team_rewards): goal (+10 when both stand on the target,
    -0.1 otherwise; with --target_potential the arrival term), per_step (the assignment's
    table: +2 on every step with exactly one agent on the target) or arrival (+2 on a step
    on which an agent first reaches it); one team value per step"""
    target_potential: float = 4.0
    """potential-based shaping for learning only (Ng et al. 1999), >= 0: adds
    gamma * Phi(s') - Phi(s) with Phi = this value per agent on the target (an arrival pays
    about +Phi, a departure costs Phi; 0 = none)"""
    potential_credit: str = "agent"
    """whose arrivals the arrival term pays each agent for: agent (its own only, a potential
    per agent; Devlin and Kudenko 2011) or team (both agents', one team value per step)"""
    total_steps: int = 300_000
    """environment steps per run, summed over the parallel environments (1 or more)"""
    num_episodes: int = 0
    """if positive, train for this many finished episodes instead of --total_steps"""
    num_envs: int = 64
    """parallel environments that collect experience"""
    batch_size: int = 128
    """transitions per gradient update"""
    lr: float = 5e-4
    """Adam learning rate at the start (finite, > 0)"""
    lr_end_factor: float = 0.03
    """final learning rate as a fraction of lr (0..1), reached linearly at the end of the run"""
    gamma: float = 0.99
    """discount factor, in [0, 1)"""
    n_step: int = 3
    """steps of reward in each TD target (1 or more): r_t + ... + gamma^(n-1) r_(t+n-1) +
    gamma^n max Q(s_(t+n)), fewer where the episode ends first (no bootstrap at a terminal)"""
    epsilon_start: float = 1.0
    """initial exploration rate, in [0, 1]"""
    epsilon_end: float = 0.05
    """final exploration rate, in [0, epsilon_start]"""
    epsilon_decay: float = 0.0
    """the course skeleton's multiplicative factor in (0, 1): after each finished episode
    epsilon <- max(epsilon_end, epsilon * factor) (e.g. 0.995); 0 = linear schedule"""
    epsilon_fraction: float = 0.3
    """with --epsilon_decay 0: fraction (0, 1] of the run over which epsilon falls linearly"""
    hidden_dim: int = 128
    """units of the hidden layer"""
    target_update: int = 0
    """gradient updates (not episodes, not env steps) between hard copies of the online
    networks into the target networks, the skeleton's rule; 0 = a soft update at
    --target_tau"""
    target_tau: float = 0.005
    """with --target_update 0: after every gradient update each target network moves this
    fraction (0, 1] of the way to its online network"""
    buffer_size: int = 100_000
    """replay capacity in joint transitions (at least batch_size)"""
    learning_starts: int = 5_000
    """env steps collected before the first update: batch_size or more, below total_steps"""
    updates_per_step: int = 2
    """gradient updates per step of the parallel environments"""
    max_grad_norm: float = 10.0
    """gradient-norm clipping threshold (finite, > 0)"""
    advantage_learning: float = 0.95
    """alpha in [0, 1) of advantage learning (Bellemare et al. 2016): the TD target minus
    alpha (max_b Q_target(s, b) - Q_target(s, a)), which widens the gaps between the actions'
    values so that estimation noise no longer decides the greedy action; 0 = plain Double DQN"""
    advantage_learning_ramp: float = 0.3
    """fraction (0, 1] of the run over which alpha rises linearly from 0 to advantage_learning"""
    comm_learning: str = "dial"
    """dial: train the message head through the partner's TD loss; none: leave it untrained"""
    comm_noise: float = 1.0
    """standard deviation (finite, >= 0) of the Gaussian noise on the message logit (DIAL)"""
    dueling: bool = False
    """use the dueling architecture Q = V + (A - mean A)"""
    prioritized: bool = False
    """use proportional prioritised replay"""
    eval_interval: int = 10_000
    """environment steps between evaluations on the fixed validation episodes"""
    eval_episodes: int = 200
    """episodes of each periodic evaluation (validation episodes)"""
    keep_best: bool = True
    """end with the weights that scored best in the periodic evaluations, not the last ones"""
    select_by: str = "steps"
    """what picks checkpoints and the best seed on validation episodes (means of the greedy
    and epsilon = 0.05 results): steps (the fewest steps to success among those within one
    point of the best success rate), success (success rate) or return (trained reward)"""
    final_eval_episodes: int = 1000
    """validation episodes of the selection evaluation at the end of each run, which picks
    the best seed per mode (reported success rates come from evaluate.py)"""
    save_freq: int = 0
    """environment steps between intermediate model saves (0: save at the end only)"""
    output_dir: str = str(DEFAULT_OUTPUT_DIR)
    """folder for agent_models/ and training_logs/; a relative path is relative to the
    current folder (default: problem2/results, wherever you run from)"""
    workers: int = field(default_factory=available_cores)
    """parallel training processes (default: the available cores; at most one per run)"""
    overwrite: bool = False
    """replace a batch with other settings in --output_dir (see the rule below)"""
    map_pool: int = 0
    """0: train on the --map_seed map; N > 0: on a pool of N generated maps (grid_maps.py), a new
    one drawn at each episode start, evaluated on other generated maps (map_pool_study.py)"""
    validation_maps: int = 200
    """with --map_pool: generated validation maps of the periodic evaluations (1 or more)"""
    share_weights: bool = False
    """parameter sharing: both agents use one set of weights (same start, summed gradient),
    a departure from the assignment's independent learners"""
    coverage_bonus: float = 0.0
    """reward shaping for learning only (>= 0): added per grid cell that enters either
    agent's 3x3 view for the first time in the episode"""
    on_target_bonus: float = 0.0
    """reward shaping for learning only (>= 0): added per agent standing on the target"""

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
        """Raise :class:`SettingError` naming the first invalid field and its allowed range;
        return self."""
        for name, check in FIELD_CHECKS.items():
            check_value(name, getattr(self, name), check)
        for names, problem in cross_field_problems(self):
            raise SettingError(names[0], problem, getattr(self, names[0]))
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def hyperparameters(self) -> dict[str, Any]:
        """Every field that shapes the results (not where they go or how many processes)."""
        return {k: v for k, v in self.to_dict().items() if k not in RUN_ONLY_FIELDS}


# ------------------------------------------------------------------------ field checks
FIELD_CHECKS: dict[str, Check] = {
    "mode": mode_list,
    "seed": int_in(0, MAX_SEED),
    "num_seeds": int_in(1),
    "seeds": seed_list,
    "map_seed": int_in(0, MAX_SEED),
    "grid_size": grid_sides,
    "max_steps": int_in(1),
    "reward_mode": one_of("goal", "per_step", "arrival"),
    "potential_credit": one_of("agent", "team"),
    "target_potential": number_in(0.0, math.inf, high_open=True),
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
    "epsilon_decay": epsilon_decay,
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
    "dueling": boolean,
    "prioritized": boolean,
    "eval_interval": int_in(1),
    "eval_episodes": int_in(1),
    "keep_best": boolean,
    "select_by": one_of(*SELECT_BY),
    "final_eval_episodes": int_in(1),
    "save_freq": int_in(0),
    "output_dir": folder,
    "workers": int_in(1),
    "overwrite": boolean,
    "map_pool": int_in(0, MAX_POOL_SIZE),
    "validation_maps": int_in(1, MAX_POOL_SIZE),
    "share_weights": boolean,
    "coverage_bonus": number_in(0.0, math.inf, high_open=True),
    "on_target_bonus": number_in(0.0, math.inf, high_open=True),
}


def cross_field_problems(cfg: TrainConfig) -> list[tuple[tuple[str, ...], str]]:
    """Settings that are each valid but break training together: (fields, problem)."""
    problems = []
    if cfg.epsilon_end > cfg.epsilon_start:
        problems.append((("epsilon_end",), f"must not exceed epsilon_start {cfg.epsilon_start}"))
    if cfg.buffer_size < cfg.batch_size:
        problems.append((("buffer_size",), f"must be at least batch_size {cfg.batch_size}"))
    if cfg.learning_starts < cfg.batch_size:
        problems.append((("learning_starts",), f"must be at least batch_size {cfg.batch_size}"))
    try:
        generate_map(cfg.grid_shape(), cfg.map_seed)
    except ValueError as error:
        problems.append((("map_seed",), f"gives no usable map on this grid ({error})"))
    return problems


assert set(FIELD_CHECKS) == {f.name for f in dataclasses.fields(TrainConfig)}


# ------------------------------------------------------------------------------ the CLI
def field_docs(cls: type) -> dict[str, str]:
    """The string literal that follows each field in the class body (whitespace joined)."""
    body = ast.parse(inspect.getsource(cls)).body[0].body
    return {
        statement.target.id: " ".join(following.value.value.split())
        for statement, following in zip(body, body[1:], strict=False)
        if isinstance(statement, ast.AnnAssign)
        and isinstance(following, ast.Expr)
        and isinstance(following.value, ast.Constant)
    }


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


OUTPUT_RULE = """\
Outputs (in --output_dir): agent_models/ (TorchScript pairs, manifest.json, map.json,
hyperparameters.json) and training_logs/ (one CSV per run, <run>_selection.json, curves,
timing.json).

A batch is written into a hidden staging folder inside --output_dir and moved into place
only when every run has finished, so the folder holds one whole batch or the previous one.
Into a folder that holds a batch with other settings (or model files without a manifest)
training refuses unless --overwrite is given; a re-run with identical settings replaces
it. Settings other than the defaults never go into the default folder without --overwrite
(choose another --output_dir). Interrupted with Ctrl-C, the batch leaves the evaluation
rows it measured in <output_dir>/interrupted/training_logs/ and the results untouched.
Stale temporary files of killed runs are removed at the next start."""


def build_parser(cls: type = TrainConfig) -> argparse.ArgumentParser:
    """One flag per dataclass field, in both spellings, with the field's docstring as help."""
    parser = argparse.ArgumentParser(
        description="Train the two agents (Problem 2).",
        epilog=OUTPUT_RULE,
        formatter_class=argparse.RawDescriptionHelpFormatter,  # the epilog's paragraphs kept
    )
    docs = field_docs(cls)
    for spec in dataclasses.fields(cls):
        factory = spec.default_factory
        default = spec.default if factory is dataclasses.MISSING else factory()
        names = list(dict.fromkeys([f"--{spec.name}", f"--{spec.name.replace('_', '-')}"]))
        options: dict[str, Any] = {"dest": spec.name, "default": default}
        options["help"] = docs.get(spec.name, "") + (
            "" if spec.name == "output_dir" else " (default: %(default)s)"
        )
        if isinstance(default, bool):
            options["action"] = argparse.BooleanOptionalAction
        elif spec.name in LIST_FLAGS:
            item_type, options["metavar"] = LIST_FLAGS[spec.name]
            options |= {"nargs": "+", "action": ListAction, "item_type": item_type}
        else:
            options["type"] = type(default)
        parser.add_argument(*names, **options)
    return parser


LIST_FLAGS: dict[str, tuple[Callable[[str], Any], str]] = {
    "mode": (str, "MODE"),
    "seeds": (int, "SEED"),
    "grid_size": (int, "N"),
}


def parse_config(
    argv: Sequence[str] | None = None, parser: argparse.ArgumentParser | None = None
) -> TrainConfig:
    """Parse and validate; a bad value raises :class:`SettingError` (a ValueError)."""
    values = vars((parser or build_parser()).parse_args(argv))
    if isinstance(values.get("mode"), list):
        values["mode"] = ",".join(values["mode"])
    return TrainConfig(**values).validate()


def parse_config_or_exit(
    argv: Sequence[str] | None = None,
    extra_check: Callable[[TrainConfig], None] | None = None,
) -> TrainConfig:
    """Parse and validate as the CLI does: a bad value is an argparse usage error (exit 2)
    naming the flag, the value and the allowed range. ``extra_check`` (e.g. the output
    folder rule) may raise SettingError too."""
    parser = build_parser()
    try:
        cfg = parse_config(argv, parser)
        if extra_check is not None:
            extra_check(cfg)
    except SettingError as error:
        parser.error(error.usage())
    return cfg
