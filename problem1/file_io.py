"""Result files and console output that behave the same on every platform and every rerun.

Each file is written under a temporary name in its folder, then renamed, so an
interrupted run never leaves a half-written file; a whole result set is written into a
hidden staging folder first and moved into place at the end (:func:`staged_folder`).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import shutil
import sys
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

JSON_DIGITS = 10  # significant digits of floats in JSON files: last-bit noise never shows
STAGING_PREFIX = ".staging"


def shown(path: str | Path) -> str:
    """``path`` as a console line shows it: relative to the current folder when inside it."""
    path, here = Path(path).resolve(), Path.cwd().resolve()
    return str(path.relative_to(here)) if path.is_relative_to(here) else str(path)


def make_console_safe() -> None:
    """Let stdout/stderr replace characters the console cannot encode (e.g. cp1252
    on Windows) instead of raising ``UnicodeEncodeError``."""
    for stream in (sys.stdout, sys.stderr):
        if isinstance(stream, io.TextIOWrapper):
            stream.reconfigure(errors="replace")


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


def rounded(data: Any, digits: int = JSON_DIGITS) -> Any:
    """``data`` with every float rounded to ``digits`` significant digits (nested lists and
    dicts); NaN and infinity are refused."""
    if isinstance(data, dict):
        return {key: rounded(value, digits) for key, value in data.items()}
    if isinstance(data, list | tuple):
        return [rounded(value, digits) for value in data]
    if isinstance(data, float):
        if not math.isfinite(data):
            raise ValueError(f"cannot write {data} to JSON: results must be finite")
        return float(f"{data:.{digits}g}")
    return data


def atomic_save_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as UTF-8 JSON, floats with :data:`JSON_DIGITS` significant digits."""
    text = json.dumps(rounded(data), indent=2, allow_nan=False) + "\n"
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def atomic_save_npz(path: str | Path, **arrays: Any) -> Path:
    """Like ``np.savez``, but byte-identical on reruns (fixed zip timestamps)."""

    def write(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as archive:
            for name, value in arrays.items():
                entry = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                with archive.open(entry, "w") as stream:
                    np.lib.format.write_array(stream, np.asarray(value), allow_pickle=False)

    return atomic_write(path, write)


def atomic_save_figure(path: str | Path, figure: Any, dpi: int = 200) -> Path:
    """Save a matplotlib figure (format taken from the suffix: PNG, or SVG for line art),
    byte-identical on reruns (no date, fixed SVG element ids)."""

    def write(tmp: Path) -> None:
        metadata = {"Date": None} if tmp.suffix == ".svg" else None
        with matplotlib.rc_context({"svg.hashsalt": "gridworld"}):
            figure.savefig(tmp, dpi=dpi, bbox_inches="tight", metadata=metadata)

    return atomic_write(path, write)


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Delete what an interrupted run left in ``folder`` and ``folder/visualizations``:
    temporary files (``.name.tmpPID.ext``) and staging folders. Returns what was removed."""
    removed = []
    for place in (folder, folder / "visualizations"):
        if not place.is_dir():
            continue
        for entry in sorted(place.glob(".*")):
            if entry.is_dir() and entry.name.startswith(STAGING_PREFIX):
                shutil.rmtree(entry)
                removed.append(entry)
            elif entry.is_file() and ".tmp" in entry.name:
                entry.unlink()
                removed.append(entry)
    return removed


@contextmanager
def staged_folder(destination: Path) -> Iterator[Path]:
    """Yield an empty hidden folder inside ``destination``; on success move every file
    written there to the same relative place under ``destination``, on error drop it.

    Readers still check the run id stored in each file, since the final moves are
    one file at a time.
    """
    staging = destination / f"{STAGING_PREFIX}{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        yield staging
        for file in sorted(p for p in staging.rglob("*") if p.is_file()):
            target = destination / file.relative_to(staging)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(file, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def settings_id(settings: dict[str, Any]) -> str:
    """A short id of a run's settings, stored in each of its files so that readers can
    refuse files from different runs (equal settings give equal files)."""
    text = json.dumps(rounded(settings), sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]
