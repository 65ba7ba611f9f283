"""What every command of Problem 2 does first: check the packages it needs, make a console
that cannot show every character print '?', ask for reproducible matrix products; and the
atomic file writes (under a temporary name in the target folder, then ``os.replace`` onto the
real name, so an interrupted run never leaves a half-written file). Standard library only: a
command imports it first, so outside the project's virtual environment it stops with one line
saying what to do instead of Python's bare ``No module named 'torch'``. Where a training batch
may go and how it is written is ``output_folder.py``."""

from __future__ import annotations

import importlib.util
import json
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

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


def make_console_safe() -> None:
    """Print '?', not a UnicodeEncodeError, for what a console (Windows' cp1252) cannot show."""
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")


def use_reproducible_matmul() -> None:
    """Make matrix products take MKL's AVX2 code path on every x86 CPU with AVX2 (Intel or
    AMD, AVX-512 or not; MKL's conditional numerical reproducibility), so a seed trains the
    same bytes on any of them. Every entry point calls it first: it takes effect at the
    process's first matrix product, and worker processes inherit it. A value set by the user
    is kept."""
    os.environ.setdefault("MKL_CBWR", "AVX2")


@contextmanager
def temporary_path_for(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` (its folder created if needed); move it onto
    ``path`` if the block succeeds, remove it on error."""
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    temporary = final.with_name(f".{final.name}.tmp.{os.getpid()}")
    try:
        yield temporary
        os.replace(temporary, final)
    finally:
        temporary.unlink(missing_ok=True)


def write_json_atomic(path: str | Path, data: Any) -> None:
    """Write ``data`` as indented JSON (with a final newline) to ``path`` atomically."""
    with temporary_path_for(path) as temporary:
        text = json.dumps(data, indent=2, allow_nan=False) + "\n"
        temporary.write_text(text, encoding="utf-8", newline="\n")


def shown(path: str | Path) -> str:
    """``path`` as a console line shows it: relative to the current folder when inside it."""
    path, here = Path(path).resolve(), Path.cwd().resolve()
    return str(path.relative_to(here)) if path.is_relative_to(here) else str(path)


require_packages()
