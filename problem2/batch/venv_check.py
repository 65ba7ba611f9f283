"""Imported first by Problem 2's commands (standard library only, before numpy and torch): run
outside the project's virtual environment, a command stops with one line saying what to do
instead of Python's bare ``No module named 'torch'``."""

from __future__ import annotations

import importlib.util
import sys

REQUIRED = ("numpy", "torch", "matplotlib")
ADVICE = (
    "activate the project's virtual environment first (source .venv/bin/activate; Windows: "
    ".venv\\Scripts\\activate) or run the make target from the repository root (make creates "
    ".venv); see the README"
)


def missing_packages(names: tuple[str, ...] = REQUIRED) -> list[str]:
    """The packages of ``names`` this Python cannot import."""
    return [name for name in names if importlib.util.find_spec(name) is None]


def require_packages(names: tuple[str, ...] = REQUIRED) -> None:
    """Exit (status 1) naming the missing packages and the fix, if any is missing."""
    missing = missing_packages(names)
    if missing:
        sys.exit(f"{', '.join(missing)} not found by {sys.executable}: {ADVICE}")


require_packages()
