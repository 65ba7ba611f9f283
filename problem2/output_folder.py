"""Where a training batch goes, for ``train.py`` and the studies: which folder may be used
(:func:`check_output_dir`: never a code folder or a folder of other files; another batch's
settings only with ``--overwrite``), the batch written into a hidden staging folder and moved
into place whole (:func:`staged_batch`), the rows of an interrupted batch kept in
``interrupted/<n>/``, stale temporaries of killed runs removed, and worker processes that stop
with their parent (:func:`start_worker`); the finished batch's record, whose manifest
evaluate.py checks (:func:`record_batch`). Standard library only."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import safety

PROBLEM2 = Path(__file__).resolve().parent
REPOSITORY = PROBLEM2.parent
MANIFEST = "manifest.json"  # written last: a folder with one holds a complete batch
INTERRUPTED = "interrupted"
EVALUATION = "evaluation_results"  # evaluate.py's outputs beside agent_models/
BATCH_ENTRIES = ("agent_models", "training_logs", EVALUATION, INTERRUPTED)


class FolderError(ValueError):
    """An output folder refused before any work; the message says why and what to do."""


def code_folder(root: Path) -> Path | None:
    """The code folder that ``root`` is or lies in, if any: a package (``__init__.py``) or a
    folder of the repository other than problem2 holding source files (problem1, report),
    and problem2 or the repository itself."""
    if root in (PROBLEM2, REPOSITORY):
        return root
    for path in (root, *root.parents):
        if path == REPOSITORY or not path.is_relative_to(REPOSITORY):
            return None
        if (path / "__init__.py").is_file():
            return path
        in_repository = path.parent == REPOSITORY and path != PROBLEM2
        if in_repository and (any(path.glob("*.py")) or any(path.glob("*.typ"))):
            return path
    return None


def foreign_entries(root: Path, default_dir: Path) -> list[str]:
    """The visible entries of folder ``root`` that no batch writes (the default folder
    ``default_dir`` also holds the studies)."""
    allowed = {*BATCH_ENTRIES, *(["studies"] if root == default_dir else [])}
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if p.name not in allowed and p.name[0] != ".")


PER_RUN_SETTINGS = ("mode", "seed", "num_seeds", "seeds")  # an identity lists modes, seeds


def differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``key old -> new`` for each setting in which two batch identities differ (an identity:
    ``modes``, ``seeds`` and the ``hyperparameters``, as a manifest records them)."""
    before, after = (
        {k: v for k, v in ident.get("hyperparameters", {}).items() if k not in PER_RUN_SETTINGS}
        | {"modes": ident.get("modes"), "seeds": ident.get("seeds")}
        for ident in (old, new)
    )
    keys = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    return [f"{k} {before.get(k)!r} -> {after.get(k)!r}" for k in keys]


def check_output_dir(
    root: Path, identity: dict[str, Any], overwrite: bool, default_dir: Path, default: dict
) -> None:
    """Refuse (:class:`FolderError`) a folder that is a file, lies in the code or holds other
    files; unless ``overwrite``, also one holding a batch of other settings than ``identity``
    (its manifest's), results without a manifest, or settings other than ``default`` in the
    default results folder ``default_dir``. A batch of identical settings is replaced."""
    if root.exists() and not root.is_dir():
        raise FolderError(f"must be a folder, not a file ({safety.shown(root)})")
    code = code_folder(root)
    if code is not None:
        named = code.relative_to(REPOSITORY).as_posix()  # e.g. problem2/analysis
        if code == REPOSITORY:
            where = "is the repository's root (code)"
        elif code == root:
            where = f"is the code folder {named}"
        else:
            where = f"lies in the code folder {named}"
        raise FolderError(
            f"{where}: choose a folder for results, e.g. --output_dir my_run from problem2/ or "
            "a folder under problem2/results/"
        )
    others = foreign_entries(root, default_dir)
    if others:
        shown = ", ".join(others[:5]) + (", ..." if len(others) > 5 else "")
        raise FolderError(
            f"holds files that are not a training batch's ({safety.shown(root)}: {shown}); a batch "
            "goes into a new or empty folder or one holding a batch: choose another --output_dir"
        )
    if overwrite:
        return
    remedy = (
        "choose another --output_dir, or pass --overwrite to replace the batch in "
        + safety.shown(root)
    )
    manifest = root / "agent_models" / MANIFEST
    if manifest.is_file():
        try:
            changed = differences(json.loads(manifest.read_text("utf-8")), identity)
        except (OSError, ValueError, AttributeError):
            changed = ["its manifest.json is unreadable"]
        if changed:
            raise FolderError(f"holds a batch with other settings ({'; '.join(changed)}): {remedy}")
    elif root != default_dir and any(
        not p.name.startswith(".")
        for sub in ("agent_models", "training_logs")
        if (root / sub).is_dir()
        for p in (root / sub).iterdir()
    ):
        raise FolderError(f"holds results without a manifest.json (of an unknown batch): {remedy}")
    if root == default_dir and differences(default, identity):
        raise FolderError(
            "is the default results folder (the committed results of the default settings), "
            f"and these settings differ ({'; '.join(differences(default, identity))}): {remedy}"
        )


# ------------------------------------------------------------------ the batch, written aside
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


@contextmanager
def staged_batch(root: Path) -> Iterator[Path]:
    """Yield a hidden staging folder in ``root`` with empty ``agent_models/`` and
    ``training_logs/``; when the block ends, install it into ``root`` (:func:`install`). On
    Ctrl-C it becomes ``interrupted/<n>/`` (its CSV rows are what was measured; an earlier
    interrupted batch is kept) and the KeyboardInterrupt goes on; on any other error it is
    deleted, with the folders this batch created."""
    created = next((p for p in reversed((root, *root.parents)) if not p.exists()), None)
    for folder in (root, root / "agent_models", root / "training_logs"):
        remove_stale_temporaries(folder)
    staging = root / f".staging.{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "agent_models").mkdir(parents=True)
    (staging / "training_logs").mkdir()
    try:
        yield staging
        install(staging, root)
    except KeyboardInterrupt:  # keep what it measured (no manifest: no reader takes it for results)
        kept = root / INTERRUPTED / str(1 + len(list((root / INTERRUPTED).glob("*"))))
        kept.parent.mkdir(exist_ok=True)
        os.replace(staging, kept)
        print(f"\ninterrupted: the rows measured so far are in {kept}", file=sys.stderr)
        raise
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if created and created.is_dir() and not any(p.is_file() for p in created.rglob("*")):
            shutil.rmtree(created, ignore_errors=True)  # it holds only empty folders
        raise


def keep_out_of_git(root: Path, default_dir: Path) -> None:
    """Make a batch folder inside the repository but outside the results folder
    ``default_dir`` (a custom run, e.g. ``--output_dir my_run``) ignore itself, so that
    ``git add`` never offers it."""
    if root.is_relative_to(REPOSITORY) and not root.is_relative_to(default_dir):
        (root / ".gitignore").write_text("# a custom training run\n*\n", encoding="utf-8")


def model_digests(models_dir: Path) -> dict[str, Any] | None:
    """Each run's model checksums as the manifest in ``models_dir`` lists them (None: no
    readable manifest)."""
    try:
        runs = json.loads((models_dir / MANIFEST).read_text(encoding="utf-8"))["runs"]
        return {name: (run["sha256"], run.get("last_weights")) for name, run in runs.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def install(staging: Path, root: Path) -> None:
    """Move the finished batch into ``root``, replacing the previous one. agent_models/ goes
    last: its manifest marks a complete batch (readers find either the old one, none, or
    the new one). An evaluation of other model files (evaluation_results/) goes first, with
    the batch it evaluated; one of byte-identical models stays."""
    replaced = root / f".replaced.{os.getpid()}"
    old_models = model_digests(root / "agent_models")
    stale = (root / EVALUATION).is_dir() and (
        old_models is None or old_models != model_digests(staging / "agent_models")
    )
    if stale:
        replaced.mkdir(exist_ok=True)
        os.replace(root / EVALUATION, replaced / EVALUATION)
        print(
            f"removed {root / EVALUATION}: it evaluated the replaced batch; run evaluate.py again"
        )
    for sub in ("training_logs", "agent_models"):
        if (root / sub).exists():
            replaced.mkdir(exist_ok=True)
            os.replace(root / sub, replaced / sub)
        os.replace(staging / sub, root / sub)
    shutil.rmtree(replaced, ignore_errors=True)
    shutil.rmtree(staging, ignore_errors=True)


def model_listing(files: dict[str, str], models_dir: Path) -> dict[str, dict[str, str]]:
    """The manifest's record of a model pair: files (relative to ``models_dir``), sha256."""
    digests = {a: hashlib.sha256((models_dir / f).read_bytes()) for a, f in files.items()}
    return {"models": files, "sha256": {a: d.hexdigest() for a, d in digests.items()}}


SELECTION_MEASURES = ("success_rate", "mean_steps_to_success", "mean_return")


def record_batch(
    staging: Path,
    finals: list[dict[str, Any]],
    best: dict[str, str],
    identity: dict,
    select_by: str,
) -> None:
    """After every run, the batch's record: the wall times (``timing.json``, each run's
    ``seconds`` taken out of ``finals``), each mode's best
    pair copied to ``<mode>_agent_{A,B}.pt`` and, last, the manifest (``identity``, each run's
    selection results and model files with their sha256, which evaluate.py checks)."""
    models, logs = staging / "agent_models", staging / "training_logs"
    seconds = {f"{f['mode']}_seed{f['seed']}": round(f.pop("seconds"), 1) for f in finals}
    safety.write_json_atomic(logs / "timing.json", seconds)
    for mode, name in best.items():
        for agent in "AB":
            with safety.temporary_path_for(models / f"{mode}_agent_{agent}.pt") as temporary:
                shutil.copyfile(models / f"{name}_agent_{agent}.pt", temporary)
    runs = {}
    for final in finals:
        name = f"{final['mode']}_seed{final['seed']}"
        files = {agent: f"{name}_agent_{agent}.pt" for agent in "AB"}
        runs[name] = {"mode": final["mode"], "seed": final["seed"]}
        runs[name] |= model_listing(files, models)
        runs[name]["selection"] = {"select_by": select_by} | {
            condition: {key: final[condition][key] for key in SELECTION_MEASURES}
            for condition in ("greedy", "eps")
        }
        last = {agent: f"last_weights/{name}_agent_{agent}.pt" for agent in "AB"}
        if all((models / f).is_file() for f in last.values()):  # trained with keep_best
            runs[name]["last_weights"] = model_listing(last, models)
    manifest = {"format": 1, **identity, "runs": runs, "best": best}
    safety.write_json_atomic(models / MANIFEST, manifest)


# ------------------------------------------------------------------ worker processes
def start_worker() -> None:
    """A pool worker's initializer: Ctrl-C is the parent's to handle (it stops the pool), and
    the worker exits as soon as its parent is gone (killed, it cannot stop the pool)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()

    def exit_when_orphaned() -> None:
        while process_alive(parent) and os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=exit_when_orphaned, daemon=True).start()
