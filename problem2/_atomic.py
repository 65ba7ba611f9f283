"""Atomic file writes for problem 2: write under a temporary name in the target folder,
then ``os.replace`` it onto the real name, so an interrupted run never leaves a
half-written result behind."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def temporary_path_for(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``path``; move it onto ``path`` if the block succeeds.

    The parent folder is created if needed; the temporary file is removed on error.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    temporary = final.with_name(f".{final.name}.tmp.{os.getpid()}")
    try:
        yield temporary
        os.replace(temporary, final)
    finally:
        temporary.unlink(missing_ok=True)


def write_json_atomic(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON (with a final newline) to ``path`` atomically."""
    with temporary_path_for(path) as temporary:
        temporary.write_text(json.dumps(data, indent=2) + "\n")
    return Path(path)
