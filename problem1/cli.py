"""Command-line conventions shared by the Problem 1 scripts: one help style, flags checked
before any work starts (a bad value is an argparse usage error naming the flag)."""

from __future__ import annotations

import argparse
import importlib.util
import math
import sys
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent / "results"
REQUIRED = ("numpy", "matplotlib")


def require_packages(names: tuple[str, ...] = REQUIRED) -> None:
    """Exit (status 1) naming the missing packages and the fix: the scripts import this module
    first (standard library only), so a run outside the project's virtual environment gets
    this line instead of a bare ``No module named 'numpy'``."""
    missing = [name for name in names if importlib.util.find_spec(name) is None]
    if missing:
        sys.exit(
            f"{', '.join(missing)} not found by {sys.executable}: activate the project's "
            "virtual environment first (source .venv/bin/activate; Windows: "
            ".venv\\Scripts\\activate) or run make from the repository root (it creates .venv)"
        )


require_packages()


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Shows each flag's default and keeps the description's line breaks."""


def new_parser(description: str) -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        allow_abbrev=False, description=description, formatter_class=HelpFormatter
    )


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def discount(text: str) -> float:
    """A discount factor in [0, 1)."""
    value = _number(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"must lie in [0, 1), got {text}")
    return value


def positive_number(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def int_at_least(minimum: int):
    """Argument type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {text}")
        return value

    return parse


def folder(text: str) -> Path:
    """A folder that exists or can be created (no file in the way). Relative paths are
    taken from the current folder."""
    path = Path(text)
    for candidate in (path, *path.parents):
        if candidate.exists():
            if not candidate.is_dir():
                raise argparse.ArgumentTypeError(f"{candidate} is a file, not a folder")
            break
    return path


def add_solver_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The flags every Problem 1 solver script shares: --gamma, --epsilon, --results_dir."""
    parser.add_argument("--gamma", type=discount, default=0.95, help="discount factor, in [0, 1)")
    parser.add_argument(
        "--epsilon",
        type=positive_number,
        default=1e-4,
        help="stop at the first sweep whose sup-norm change is below this (> 0)",
    )
    add_results_dir_argument(parser)
    return parser


def add_results_dir_argument(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument(
        "--results_dir",
        "--results-dir",
        dest="results_dir",
        type=folder,
        default=RESULTS_DIR,
        help="output folder (relative to the current folder)",
    )
    return parser
