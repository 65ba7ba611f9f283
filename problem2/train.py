"""Train the two agents of Problem 2: every ablation mode, several seeds, in parallel.

    python train.py                      # 3 modes x 10 seeds on the default map (seed 641)
    python train.py --mode full --seeds 641 642 --total_steps 200000 --output_dir my_run
    python train.py --help               # every hyperparameter, with its meaning and range

The algorithm is ``trainer.DQNTrainer``; :class:`MultiAgentTrainer` adds the course
skeleton's interface to it. The hyperparameters are in ``train_config.py`` and their rules
in ``settings.py``; the command line here has one flag per :class:`~settings.BatchConfig`
field (both spellings, the field's help and default; list flags take ``--seeds 641 642`` or
``--seeds 641,642``), checks every value before any work, and refuses the flags that left
the core with a message naming the command that now owns them. The batch is in
``batch/experiments.py``; :func:`apply_observation_mask` is the course's masking function
(the learner applies the same mask, ``models.observation_mask``, inside its networks' inputs).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import safety  # noqa: F401  (first: checks the packages, stdlib only)
import torch
from batch.experiments import (
    INTERRUPTED,
    MANIFEST,
    SavingTrainer,
    check_output_dir,
    output_root,
    run_experiments,
)
from grid_maps import NUM_ACTIONS
from models import observation_mask
from replay_buffer import ReplayBuffer
from rollout import EVAL_SEED, Rollout
from safety import make_console_safe, use_reproducible_matmul
from settings import BatchConfig, SettingError, usage, validated
from train_config import TrainConfig
from trainer import EVAL_EPSILON, step_fields

__all__ = ["EVAL_EPSILON", "MultiAgentTrainer", "TrainConfig", "apply_observation_mask", "main"]


def apply_observation_mask(obs: np.ndarray | torch.Tensor, mode: str) -> np.ndarray | torch.Tensor:
    """Zero the inputs that ablation ``mode`` hides (``models.MASKED_INPUTS``):
    ``independent`` the message and the distance (elements 9 and 10 for a 3 x 3 window),
    ``comm`` the distance, ``distance`` the message, ``full`` none. Any leading shape
    (..., obs_dim)."""
    mask = observation_mask(mode, obs.shape[-1])
    if isinstance(obs, torch.Tensor):
        return obs * torch.tensor(mask)
    return np.asarray(obs, dtype=np.float32) * mask


def config_from(args: Any) -> TrainConfig:
    """A TrainConfig as given, or one built and validated from any namespace, e.g. the course
    skeleton's (``mode`` missing or ``all`` means ``full``; output under ``./results``;
    other attributes ignored, ``grid_size`` among them: the map comes from the environment)."""
    if isinstance(args, TrainConfig):
        return args
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    settings = {k: v for k, v in vars(args).items() if k in known and v is not None}
    if settings.get("mode", "all") == "all":
        settings["mode"] = "full"
    settings.setdefault("output_dir", "results")  # like the skeleton
    return validated(TrainConfig(**settings))


class MultiAgentTrainer(SavingTrainer):
    """The course skeleton's trainer: the learner (:class:`trainer.DQNTrainer`, writing policy
    files as :class:`~batch.experiments.SavingTrainer` does) built from a bare
    ``argparse.Namespace`` (or a TrainConfig) with ``select_action``, ``train_episode``,
    ``evaluate`` and ``network_A`` / ``network_B`` on top."""

    def __init__(self, env: Any, args: Any) -> None:
        super().__init__(env, config_from(args))
        # The course's buffer: push / sample, and every push checked (transitions by hand).
        self.replay_buffer = ReplayBuffer(self.cfg.buffer_size, seed=self.seed)
        self._episode_rollout: Rollout | None = None  # the one-environment rollout

    @property
    def network_A(self) -> torch.nn.Module:
        """Agent A's network as a standalone AgentDQN (a snapshot)."""
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
        under the reward the trainer learns from (unshaped)."""
        summary = self.evaluation_summary(num_episodes, epsilon, seed)
        return summary["mean_return"], summary["success_rate"]

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
        """Into a buffer first filled by hand with the course's ten fields, push one-step
        transitions of those fields; otherwise the core's n-step transitions."""
        buffer = self.replay_buffer
        if not len(buffer) or "discount" in buffer.field_names:
            return super().store(
                rollout, actions, messages, rewards, next_obs, terminated, truncated
            )
        buffer.push_batch(
            **step_fields(rollout.obs, actions, messages),
            reward=rewards,
            next_state_A=next_obs[:, 0],
            next_state_B=next_obs[:, 1],
            done=terminated,
        )


# ------------------------------------------------------------------ the command line
MAP_POOL_COMMAND = "python -m studies.map_pool_study"
MOVED_FLAGS = {  # flag -> where it lives now
    "map_pool": MAP_POOL_COMMAND,
    "validation_maps": MAP_POOL_COMMAND,
    "share_weights": MAP_POOL_COMMAND,
    "coverage_bonus": MAP_POOL_COMMAND,
    "on_target_bonus": MAP_POOL_COMMAND,
    "prioritized": "no command: prioritised replay was retired from training "
    "(replay_buffer.PrioritizedReplayBuffer remains, for the course interface)",
    "dueling": "no command: the dueling head was retired from training "
    "(models.DuelingDQN remains, for the course interface)",
}


class MovedFlag(argparse.Action):
    """A flag that ``train.py`` no longer takes: a usage error saying where it went."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, nargs="?", **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: ANN001
        owner = MOVED_FLAGS[self.dest]
        parser.error(f"{option_string} is not a train.py flag any more; it belongs to {owner}")


OUTPUT_RULE = """\
Outputs (in --output_dir): agent_models/ (TorchScript pairs, manifest.json, map.json,
hyperparameters.json) and training_logs/ (one CSV per run, <run>_selection.json, curves,
timing.json).

A batch is written into a hidden staging folder inside --output_dir and moved into place
only when every run has finished, so the folder holds one whole batch or the previous one.
Into a folder that holds a batch with other settings (or model files without a manifest)
training refuses unless --overwrite is given; a re-run with identical settings replaces
it. Settings other than the defaults never go into the default folder without --overwrite
(choose another --output_dir). A folder of other files, or one inside the code (e.g.
analysis), is refused even with --overwrite. A replaced batch's evaluation_results/ goes
with it (unless the new models are byte-identical): run evaluate.py again. Interrupted
with Ctrl-C, the batch leaves the evaluation rows it measured in
<output_dir>/interrupted/training_logs/ and the results untouched.
Stale temporary files of killed runs are removed at the next start."""


def build_parser(cls: type = BatchConfig) -> argparse.ArgumentParser:
    """One flag per dataclass field, in both spellings, with the field's help and default."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description="Train the two agents (Problem 2).",
        epilog=OUTPUT_RULE,
        formatter_class=argparse.RawDescriptionHelpFormatter,  # the epilog's paragraphs kept
    )
    for spec in dataclasses.fields(cls):
        factory = spec.default_factory
        default = spec.default if factory is dataclasses.MISSING else factory()
        names = list(dict.fromkeys([f"--{spec.name}", f"--{spec.name.replace('_', '-')}"]))
        options: dict[str, Any] = {"dest": spec.name, "default": default}
        # A default that is a path of this machine or the core count: its help names it.
        shown_default = "" if "(default:" in spec.metadata["help"] else " (default: %(default)s)"
        options["help"] = spec.metadata["help"] + shown_default
        if isinstance(default, bool):
            options["action"] = argparse.BooleanOptionalAction
        elif spec.metadata["items"]:
            item_type, options["metavar"] = spec.metadata["items"]
            options |= {"nargs": "+", "action": ListAction, "item_type": item_type}
        else:
            options["type"] = type(default)
        parser.add_argument(*names, **options)
    fields = {spec.name for spec in dataclasses.fields(cls)}
    for name in (name for name in MOVED_FLAGS if name not in fields):  # a subclass may own it
        spellings = {name, name.replace("_", "-")}
        flags = [f"--{s}" for s in sorted(spellings)] + [f"--no-{s}" for s in sorted(spellings)]
        parser.add_argument(
            *flags,
            dest=name,
            action=MovedFlag,
            default=argparse.SUPPRESS,
            help=argparse.SUPPRESS,
        )
    return parser


def parse_config(
    argv: Sequence[str] | None = None, parser: argparse.ArgumentParser | None = None
) -> BatchConfig:
    """Parse and validate; bad values raise :class:`SettingError` (a ValueError)."""
    values = vars((parser or build_parser()).parse_args(argv))
    if isinstance(values.get("mode"), list):
        values["mode"] = ",".join(values["mode"])
    return validated(BatchConfig(**values))


def parse_config_or_exit(
    argv: Sequence[str] | None = None,
    extra_check: Callable[[BatchConfig], None] | None = None,
) -> BatchConfig:
    """Parse and validate as the CLI does: bad values are an argparse usage error (exit 2)
    naming, a line each, the flag, the value and the allowed range. ``extra_check`` (e.g.
    the output folder rule) may raise SettingError too."""
    parser = build_parser()
    try:
        cfg = parse_config(argv, parser)
        if extra_check is not None:
            extra_check(cfg)
    except SettingError as error:
        parser.error(usage(error))
    return cfg


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


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """Train every requested mode and seed (in parallel) and write models, logs and curves.
    Every setting and the output folder are checked first (a usage error names the flag)."""
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    cfg = parse_config_or_exit(argv, extra_check=check_output_dir)
    if (output_root(cfg) / "agent_models" / MANIFEST).is_file():
        print(f"the batch in {output_root(cfg)} is replaced when this one is complete")
    try:
        finals = run_experiments(cfg)
    except KeyboardInterrupt:
        kept = output_root(cfg) / INTERRUPTED / "training_logs"
        print(f"\ninterrupted: the rows measured so far are in {kept}", file=sys.stderr)
        raise
    print(f"{'run':<22} {'selection: success greedy':>26} {'eps=0.05':>9}")
    for final in finals:
        print(
            f"{final['mode'] + ' seed ' + str(final['seed']):<22} "
            f"{final['greedy']['success_rate']:26.3f} {final['eps']['success_rate']:9.3f}"
        )
    print(f"wrote {output_root(cfg)} (success on validation episodes; evaluate.py tests)")
    return finals


if __name__ == "__main__":
    # Frozen, the modules' objects (torch alone has ~170 k) are skipped by the collector's full
    # passes during the run and at exit (~0.3 s sooner); freezing again adds what the run imported.
    gc.freeze()
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
    gc.freeze()
