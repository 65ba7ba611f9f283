"""Batch plumbing for problem 2: what a program does first (a console that cannot show
every character, reproducible matrix products), atomic file writes (under a temporary name in
the target folder, then ``os.replace`` onto the real name, so an interrupted run never leaves
a half-written result), stale temporaries, worker processes, the progress line, and the
policy files: a network behind its observation mask as TorchScript, the same weights giving
the same bytes anywhere."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import multiprocessing as mp
import os
import queue
import shutil
import signal
import sys
import threading
import time
import warnings
import zipfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch
from grid_maps import check_grid
from models import MaskedPolicy, MessagingQNetwork, exportable_copy, observation_mask
from torch import nn


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


def save_map(path: str | Path, grid: np.ndarray) -> None:
    """Write a validated map to ``path`` as JSON ``{"grid": [[...], ...]}`` (atomically)."""
    write_json_atomic(path, {"grid": check_grid(grid).tolist()})


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


def remove_stale_temporaries(folder: str | Path) -> list[Path]:
    """Delete the hidden temporary files and folders (``.<name>.tmp.<pid>``, ``.staging.<pid>``,
    ``.replaced.<pid>``) in ``folder`` whose process no longer runs; return what was removed.
    Those of running processes (another training writing here) are left alone."""
    folder = Path(folder)
    removed = []
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        pid = path.name.rsplit(".", 1)[-1]
        if not (path.name.startswith(".") and pid.isdigit()) or process_alive(int(pid)):
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
        removed.append(path)
    return removed


# ---------------------------------------------- worker processes and the progress line
_progress_queue: Any = None  # set in each worker by _start_worker


def _start_worker(parent_pipe: Any, progress_queue: Any) -> None:
    """Pool initializer: ignore Ctrl-C; exit as soon as the parent's end of the pipe closes."""
    global _progress_queue
    _progress_queue = progress_queue
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def exit_when_parent_is_gone() -> None:
        with contextlib.suppress(EOFError, OSError):
            parent_pipe.recv()  # the parent never sends: this returns only by EOFError
        os._exit(1)

    threading.Thread(target=exit_when_parent_is_gone, daemon=True).start()


def _run_job(job: Callable[..., Any], args: tuple) -> Any:
    return job(*args, _progress_queue)


def run_jobs(
    job: Callable[..., Any], arguments: Sequence[tuple], workers: int, progress: ProgressLine
) -> list[Any]:
    """``job(*args, progress_sink)`` for each args of ``arguments``, in order, using at most
    ``workers`` processes (capped by the number of jobs); ``progress_sink.put(item)`` feeds
    ``progress``. Returns the results in the order of ``arguments``."""
    workers = min(workers, len(arguments))
    if workers <= 1:
        results = []
        for args in arguments:
            results.append(job(*args, progress))
            progress.runs_done += 1
        progress.close()
        return results
    context = mp.get_context("spawn")
    receive_end, send_end = context.Pipe(duplex=False)
    progress_queue = context.Queue()
    pool = context.Pool(workers, _start_worker, (receive_end, progress_queue))
    try:
        pending = [pool.apply_async(_run_job, (job, args)) for args in arguments]
        while not all(p.ready() for p in pending):
            progress.runs_done = sum(p.ready() for p in pending)
            try:
                progress.put(progress_queue.get(timeout=1.0))
            except queue.Empty:
                progress.show()
        results = [p.get() for p in pending]
        pool.close()
    finally:
        pool.terminate()
        pool.join()
        send_end.close()
        progress_queue.close()
    progress.runs_done = len(arguments)
    progress.close()
    return results


class ProgressLine:
    """One progress line for a batch of runs: runs finished, env steps, speed, ETA and the
    latest evaluation (``put`` takes the runs' ``(run name, log row, seconds)``). Rewritten in
    place on a terminal; elsewhere (a file, a pipe, CI) printed every ``interval`` seconds."""

    def __init__(
        self,
        n_runs: int,
        steps_per_run: int,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        interval: float = 10.0,
    ) -> None:
        self.n_runs, self.steps_per_run, self.runs_done = n_runs, steps_per_run, 0
        self.stream = stream if stream is not None else sys.stderr
        self.clock, self.interval = clock, interval
        self.start = self.clock()
        self.last_plain = -float("inf")
        self.rows: dict[str, dict[str, Any]] = {}
        self.latest = ""

    def put(self, item: tuple[str, dict[str, Any], float]) -> None:
        self.latest, row, _ = item
        self.rows[self.latest] = row
        self.show()

    def text(self) -> str:
        elapsed = self.clock() - self.start
        if not self.steps_per_run:  # jobs without env steps (e.g. evaluations): count, time
            return f"[{self.runs_done}/{self.n_runs} runs] {elapsed:.0f} s"
        total = self.n_runs * self.steps_per_run
        done = sum(min(row["env_steps"], self.steps_per_run) for row in self.rows.values())
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = f"{(total - done) / rate / 60:.1f} min" if rate > 0 else "?"
        line = (
            f"[{self.runs_done}/{self.n_runs} runs] {done:,}/{total:,} env steps "
            f"{rate:,.0f}/s ETA {eta}"
        )
        if self.latest:
            row = self.rows[self.latest]
            line += (
                f" | {self.latest} eps {row['epsilon']:.2f} success "
                f"{row['eval_success_eps']:.2f} (greedy {row['eval_success_greedy']:.2f})"
            )
        return line

    def _is_terminal(self) -> bool:
        return hasattr(self.stream, "isatty") and self.stream.isatty()

    def show(self, final: bool = False) -> None:
        if self._is_terminal():
            width = max(20, shutil.get_terminal_size().columns - 1)
            self.stream.write("\r" + self.text()[:width].ljust(width))
        elif final or self.clock() - self.last_plain >= self.interval:
            self.last_plain = self.clock()
            self.stream.write(self.text() + "\n")
        self.stream.flush()

    def close(self) -> None:
        self.show(final=True)
        if self._is_terminal():
            self.stream.write("\n")
            self.stream.flush()


# ------------------------------------------------ policy files (TorchScript, byte-stable)
@contextmanager
def quiet_torchscript() -> Iterator[None]:
    """torch 2.13 marks ``torch.jit`` deprecated, but the course requires TorchScript files
    that load with ``torch.jit.load`` alone, so the warning is expected here."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"`torch\.jit\.\w+` is deprecated", DeprecationWarning)
        yield


def export_policy(
    network: MessagingQNetwork,
    mask: str | Sequence[float] | np.ndarray | torch.Tensor,
    path: str | Path,
) -> Path:
    """Script ``network`` behind ``mask`` (an ablation name, for any input_dim, or input_dim
    numbers) and save it atomically with ``torch.jit.save``. ``network`` itself is left
    untouched (a CPU copy in eval mode is exported). Returns the path written."""
    input_dim = network.hidden.in_features
    if isinstance(mask, str):
        mask = observation_mask(mask, input_dim)
    elif isinstance(mask, torch.Tensor):
        mask = mask.detach().cpu().numpy()
    mask_tensor = torch.from_numpy(np.array(mask, dtype=np.float32)).flatten()  # a copy
    if mask_tensor.numel() != input_dim:
        raise ValueError(f"mask has {mask_tensor.numel()} elements; the network takes {input_dim}")
    return save_scripted(MaskedPolicy(exportable_copy(network), mask_tensor), path)


def save_scripted(module: nn.Module, path: str | Path) -> Path:
    """Script ``module`` and save it atomically, the same weights giving the same bytes
    anywhere (:func:`without_debug_sources`). Returns the path written."""
    # Saving to memory first keeps the archive's inner folder name fixed ("archive", not the
    # temporary file's name), so the same weights always give byte-identical files.
    buffer = io.BytesIO()
    with quiet_torchscript():
        torch.jit.save(torch.jit.script(module), buffer)
    with temporary_path_for(path) as temporary:
        temporary.write_bytes(without_debug_sources(buffer.getvalue()))
    return Path(path)


def without_debug_sources(archive: bytes) -> bytes:
    """Make a TorchScript archive depend on its content only: drop the ``*.debug_pkl``
    entries (source maps holding this file's absolute path, which ``torch.jit.load`` does not
    need), and replace the random per-process ``.data/serialization_id`` by 40 digits of a
    SHA-256 of the other entries, so equal weights give byte-identical files anywhere."""
    source = zipfile.ZipFile(io.BytesIO(archive))
    entries = [e for e in source.infolist() if not e.filename.endswith(".debug_pkl")]
    digest = hashlib.sha256()
    for entry in entries:
        if not entry.filename.endswith("serialization_id"):
            digest.update(entry.filename.encode() + source.read(entry.filename))
    content_id = str(int(digest.hexdigest(), 16))[:40].zfill(40).encode()
    output = io.BytesIO()
    with zipfile.ZipFile(output, "w", zipfile.ZIP_STORED) as stripped:
        for entry in entries:
            data = source.read(entry.filename)
            stripped.writestr(
                entry, content_id if entry.filename.endswith("serialization_id") else data
            )
    return output.getvalue()
