"""Atomic writes: each file is written under a temporary name in its folder, then
renamed, so an interrupted run never leaves a half-written result behind."""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (same suffix); rename it onto ``path`` on
    success, delete it on error."""
    path = Path(path)
    temporary = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(temporary_path)`` and move the result to ``path``."""
    with atomic_path(path) as temporary:
        write(temporary)
    return Path(path)


def atomic_save_json(path: str | Path, data: Any) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_text(json.dumps(data, indent=2) + "\n"))


def atomic_save_npz(path: str | Path, **arrays: Any) -> Path:
    """Like ``np.savez``, but byte-identical on reruns (fixed zip timestamps)."""

    def write(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as archive:
            for name, value in arrays.items():
                entry = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                with archive.open(entry, "w") as stream:
                    np.lib.format.write_array(stream, np.asarray(value), allow_pickle=False)

    return atomic_write(path, write)


def atomic_save_figure(path: str | Path, figure: Any, dpi: int = 150) -> Path:
    """Save a matplotlib figure (format taken from the suffix)."""
    return atomic_write(path, lambda tmp: figure.savefig(tmp, dpi=dpi, bbox_inches="tight"))
