"""The command line of ``python train.py``: one flag per :class:`~train_config.TrainConfig`
field (both spellings, the field's help and default; list flags take ``--seeds 641 642`` or
``--seeds 641,642``), values checked before any work, and the flags that left the core
refused with a message naming the command that now owns them."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

from settings import SettingError
from train_config import TrainConfig

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
(choose another --output_dir). Interrupted with Ctrl-C, the batch leaves the evaluation
rows it measured in <output_dir>/interrupted/training_logs/ and the results untouched.
Stale temporary files of killed runs are removed at the next start."""


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


def build_parser(cls: type = TrainConfig) -> argparse.ArgumentParser:
    """One flag per dataclass field, in both spellings, with the field's help and default."""
    parser = argparse.ArgumentParser(
        description="Train the two agents (Problem 2).",
        epilog=OUTPUT_RULE,
        formatter_class=argparse.RawDescriptionHelpFormatter,  # the epilog's paragraphs kept
    )
    for spec in dataclasses.fields(cls):
        factory = spec.default_factory
        default = spec.default if factory is dataclasses.MISSING else factory()
        names = list(dict.fromkeys([f"--{spec.name}", f"--{spec.name.replace('_', '-')}"]))
        options: dict[str, Any] = {"dest": spec.name, "default": default}
        # The output folder's default is an absolute path of this machine: its help names it.
        shown_default = "" if spec.name == "output_dir" else " (default: %(default)s)"
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
) -> TrainConfig:
    """Parse and validate; bad values raise :class:`SettingError` (a ValueError)."""
    values = vars((parser or build_parser()).parse_args(argv))
    if isinstance(values.get("mode"), list):
        values["mode"] = ",".join(values["mode"])
    return TrainConfig(**values).validate()


def parse_config_or_exit(
    argv: Sequence[str] | None = None,
    extra_check: Callable[[TrainConfig], None] | None = None,
) -> TrainConfig:
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
