"""Batch plumbing for the studies and ``make``: the map file, stale temporaries of killed runs,
worker processes and the progress line. (What every command does first and the atomic writes
are in ``safety.py``; the policy files in ``models.py``.)"""

from __future__ import annotations

import multiprocessing as mp
import queue
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

from safety import write_json_atomic

import numpy as np
from output_folder import start_worker
from vector_env import check_grid


def save_map(path: str | Path, grid: np.ndarray) -> None:
    """Write a validated map to ``path`` as JSON ``{"grid": [[...], ...]}`` (atomically)."""
    write_json_atomic(path, {"grid": check_grid(grid).tolist()})


# ---------------------------------------------- worker processes and the progress line
_progress_queue: Any = None  # set in each worker by _start_worker


def _start_worker(progress_queue: Any) -> None:
    """Pool initializer: ``output_folder.start_worker``'s (Ctrl-C is the parent's, and
    the worker exits once its parent is gone), and the queue that feeds the progress line."""
    global _progress_queue
    _progress_queue = progress_queue
    start_worker()


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
    progress_queue = context.Queue()
    pool = context.Pool(workers, _start_worker, (progress_queue,))
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
