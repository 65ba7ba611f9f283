"""Batch plumbing for problem 2: atomic file writes (under a temporary name in the target
folder, then ``os.replace`` onto the real name, so an interrupted run never leaves a
half-written result), stale temporaries, worker processes, the progress line, a console
that cannot show every character, and the command line of ``python train.py``: one flag per
:class:`~settings.BatchConfig` field (both spellings, the field's help and default; list
flags take ``--seeds 641 642`` or ``--seeds 641,642``), values checked before any work, and the
flags that left the core refused with a message naming the command that now owns them."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import multiprocessing as mp
import os
import queue
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from grid_maps import check_grid
from settings import BatchConfig, SettingError, validated


def make_console_safe() -> None:
    """Print '?', not a UnicodeEncodeError, for what a console (Windows' cp1252) cannot show."""
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")


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


# ------------------------------------------------ the command line of python train.py
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


def build_parser(cls: type = BatchConfig) -> argparse.ArgumentParser:
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
) -> BatchConfig:
    """Parse and validate; bad values raise :class:`SettingError` (a ValueError)."""
    values = vars((parser or build_parser()).parse_args(argv))
    if isinstance(values.get("mode"), list):
        values["mode"] = ",".join(values["mode"])
    return validated(BatchConfig(**values))


def parse_config_or_exit(
    argv: Sequence[str] | None = None,
    extra_check: Callable[[BatchConfig], None] | None = None,
) -> BatchConfig:
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
