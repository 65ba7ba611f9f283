"""Atomic file writes for problem 2: write under a temporary name in the target folder,
then ``os.replace`` it onto the real name, so an interrupted run never leaves a
half-written result behind."""

from __future__ import annotations

import json
import os
import shutil
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
        text = json.dumps(data, indent=2, allow_nan=False) + "\n"
        temporary.write_text(text, encoding="utf-8", newline="\n")
    return Path(path)


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` is running (this process counts as running)."""
    if pid == os.getpid():
        return True
    if os.name == "nt":  # os.kill(pid, 0) would send CTRL_C there; ask the kernel instead
        import ctypes

        kernel32 = ctypes.windll.kernel32  # type: ignore[attr-defined]
        handle = kernel32.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
        if not handle:
            return False
        code = ctypes.c_ulong()
        running = kernel32.GetExitCodeProcess(handle, ctypes.byref(code)) and code.value == 259
        kernel32.CloseHandle(handle)
        return bool(running)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def owner_pid(path: Path) -> int | None:
    """The process id that ends a temporary name (``.name.tmp.<pid>``, ``.staging.<pid>``)."""
    suffix = path.name.rsplit(".", 1)[-1]
    return int(suffix) if path.name.startswith(".") and suffix.isdigit() else None


def remove_stale_temporaries(folder: str | Path) -> list[Path]:
    """Delete the hidden temporary files and folders (``.<name>.tmp.<pid>``, ``.staging.<pid>``,
    ``.replaced.<pid>``) in ``folder`` whose process no longer runs; return what was removed.
    Those of running processes (another training writing here) are left alone."""
    folder = Path(folder)
    removed = []
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        pid = owner_pid(path)
        if pid is None or process_alive(pid):
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
        removed.append(path)
    return removed


def first_missing_ancestor(path: Path) -> Path | None:
    """The outermost folder of ``path`` (or itself) that does not exist yet."""
    missing = None
    for folder in (path, *path.parents):
        if folder.exists():
            break
        missing = folder
    return missing


def remove_if_empty(folder: Path | None) -> None:
    """Delete ``folder`` if it holds nothing but empty folders (what a failed batch made)."""
    if folder is not None and folder.is_dir() and not any(p.is_file() for p in folder.rglob("*")):
        shutil.rmtree(folder, ignore_errors=True)
