"""What the studies share: an output folder written whole (everything goes into a staging
folder beside it, which replaces the folder only when the block succeeds: an interrupted
study leaves the previous results, never half of new ones), the timing file, a study
flag checked by a TrainConfig field's rule, a run trained into a folder with its progress
reported, the checkpoint a trainer selected, and the steps of a study's ``main``."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from safety import make_console_safe, write_json_atomic

from analysis.console import repository_path
from output_folder import PROBLEM2, code_folder, remove_stale_temporaries
from settings import check_setting
from trainer import DQNTrainer


@contextmanager
def staged_output(
    output_dir: Path, subfolders: tuple[str, ...] = ("agent_models", "training_logs")
) -> Iterator[Path]:
    """Yield an empty staging folder (with ``subfolders``) beside ``output_dir``; on success
    it replaces ``output_dir``, on error it is removed. A folder that is or holds the
    project's code is refused first (it would be replaced whole)."""
    output_dir = Path(output_dir).resolve()
    if PROBLEM2.is_relative_to(output_dir) or code_folder(output_dir) is not None:
        raise SystemExit(
            f"{repository_path(output_dir)} holds the project's code and would be replaced "
            "whole: give another --output_dir"
        )
    output_dir.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(output_dir.parent)
    staging = output_dir.parent / f".{output_dir.name}.staging.{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        staging.mkdir(parents=True)
        for name in subfolders:
            (staging / name).mkdir()
        yield staging
        replaced = output_dir.parent / f".{output_dir.name}.replaced.{os.getpid()}"
        if output_dir.exists():
            os.replace(output_dir, replaced)
        os.replace(staging, output_dir)
        shutil.rmtree(replaced, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def write_timing(path: Path, runs: list[dict[str, Any]]) -> None:
    """``timing.json``: each run's wall times (``seconds``), by ``<mode>_seed<seed>``."""
    timing = {
        f"{r['mode']}_seed{r['seed']}": {k: round(v, 1) for k, v in r["seconds"].items()}
        for r in runs
    }
    write_json_atomic(path, timing)


def check_field(name: str, value: Any) -> None:
    """Raise ``SettingError`` if ``value`` breaks TrainConfig field ``name``'s rule (checked
    alone: for a flag that is turned into other fields, e.g. a study's seed count)."""
    check_setting(name, value)


def best_env_steps(trainer: DQNTrainer) -> int:
    """Environment steps at the trainer's best checkpoint (0 before the first evaluation)."""
    best = trainer.best_checkpoint()
    return 0 if best is None else best.env_steps


def best_selection(trainer: DQNTrainer) -> dict[str, float]:
    """Validation success rates of the trainer's best checkpoint, ``greedy`` and ``eps``."""
    best = trainer.best_checkpoint()
    if best is None:
        return {}
    return {c: getattr(best, c)["success_rate"] for c in ("greedy", "eps")}


def train_into(
    trainer: DQNTrainer, folder: Path, progress: Any, start: float, label: str | None = None
) -> list[dict[str, Any]]:
    """Train ``trainer`` with its models and logs under ``folder`` (``agent_models/``,
    ``training_logs/``), sending each evaluation row to ``progress`` (a ``run_jobs`` queue, or
    None) as (``label`` or the run's name, row, seconds since ``start``). Returns the log."""
    trainer.models_dir, trainer.logs_dir = folder / "agent_models", folder / "training_logs"
    name = label or trainer.name

    def report(row: dict[str, Any]) -> None:
        if progress is not None:
            progress.put((name, row, time.perf_counter() - start))

    return trainer.train(report)


def study_main(
    argv: list[str] | None,
    parse_args: Callable[[list[str] | None], argparse.Namespace],
    run: Callable[[argparse.Namespace], dict],
    report: Callable[[dict], str],
    plot: tuple[str, Callable[[Path, dict], None]] | None = None,
) -> dict:
    """A study's ``main`` after its first step (``use_reproducible_matmul()``): a console that
    prints '?' for what it cannot show, the checked flags, then ``run(args)``; prints
    ``report(results)`` and the folder written (from the repository's root) with the time
    taken. With ``plot=(stem, draw)``, ``--plot_only`` instead redraws ``<stem>.png`` from
    ``<stem>.json`` in ``--output_dir`` (no runs)."""
    make_console_safe()
    args = parse_args(argv)
    if plot is not None and args.plot_only:
        return redraw(args.output_dir, *plot)
    start = time.perf_counter()
    results = run(args)
    print(report(results))
    print(f"wrote {repository_path(args.output_dir)} ({time.perf_counter() - start:.0f} s)")
    return results


def redraw(folder: Path, stem: str, draw: Callable[[Path, dict], None]) -> dict:
    """Draw ``<stem>.png`` in ``folder`` from its ``<stem>.json``; exit if there is none."""
    path = folder / f"{stem}.json"
    if not path.is_file():
        raise SystemExit(f"no {path.name} in {folder.resolve()}: run the study first")
    results = json.loads(path.read_text(encoding="utf-8"))
    draw(folder / f"{stem}.png", results)
    print(f"wrote {repository_path(folder / f'{stem}.png')}")
    return results


def run_command(main: Callable[[], Any]) -> Any:
    """Run a study's ``main`` as a command and return its result; Ctrl-C ends it with one
    line and exit status 130 instead of a traceback (a staging folder is cleaned up by the
    study's own ``with``)."""
    try:
        return main()
    except KeyboardInterrupt:
        print("interrupted (Ctrl-C)", file=sys.stderr)
        raise SystemExit(130) from None
