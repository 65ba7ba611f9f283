"""Run a batch of training runs (modes x seeds) and install its outputs as one whole.

Used by ``python train.py``. What goes where, and when a folder is refused, is ``OUTPUT_RULE``
in ``train.py``; the README's table of outputs names every file. ``timing.json`` (wall
times) is the only output that differs between identical reruns.
"""

from __future__ import annotations

import ast
import csv
import hashlib
import json
import os
import shutil
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from grid_maps import generate_map
from models import export_policy
from rollout import EVAL_EPSILON, VALIDATION_SEED, select_best
from safety import temporary_path_for, write_json_atomic
from settings import BatchConfig, SettingError, validated
from train_config import DEFAULT_OUTPUT_DIR
from trainer import LAST_WEIGHTS, DQNTrainer
from vector_env import VectorMultiAgentEnv

from batch.plumbing import ProgressLine, remove_stale_temporaries, run_jobs, save_map

PROBLEM2 = Path(__file__).resolve().parent.parent
REPOSITORY = PROBLEM2.parent
MANIFEST = "manifest.json"
INTERRUPTED = "interrupted"
EVALUATION = "evaluation_results"  # evaluate.py's outputs beside agent_models/
BATCH_ENTRIES = ("agent_models", "training_logs", EVALUATION, INTERRUPTED)
MODE_COLOURS = {
    "independent": "#1b9e77",
    "comm": "#d95f02",
    "distance": "#e7298a",
    "full": "#7570b3",
}
PER_RUN_SETTINGS = ("mode", "seed", "num_seeds", "seeds")  # the manifest lists modes, seeds


def run_name(mode: str, seed: int) -> str:
    return f"{mode}_seed{seed}"


def output_root(cfg: BatchConfig) -> Path:
    """``cfg.output_dir`` as an absolute path (a relative one is relative to the current folder)."""
    return Path(cfg.output_dir).resolve()


# ------------------------------------------------------------------ which folder may be used
def batch_identity(cfg: BatchConfig) -> dict[str, Any]:
    """What a batch is, as the manifest records it (compared to decide replace vs refuse)."""
    return {
        "modes": cfg.run_modes(),
        "seeds": cfg.run_seeds(),
        "map_seed": cfg.map_seed,
        "reward_mode": cfg.reward_mode,
        "hyperparameters": cfg.hyperparameters(),
    }


def identity_differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``key old -> new`` for each setting in which two batch identities differ."""
    before, after = (
        {k: v for k, v in ident.get("hyperparameters", {}).items() if k not in PER_RUN_SETTINGS}
        | {"modes": ident.get("modes"), "seeds": ident.get("seeds")}
        for ident in (old, new)
    )
    keys = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    return [f"{k} {before.get(k)!r} -> {after.get(k)!r}" for k in keys]


def holds_results(root: Path) -> bool:
    """Whether ``root`` has visible files in agent_models/ or training_logs/."""
    return any(
        not path.name.startswith(".")
        for sub in ("agent_models", "training_logs")
        if (root / sub).is_dir()
        for path in (root / sub).iterdir()
    )


def code_folder(root: Path) -> Path | None:
    """The code folder that ``root`` is or lies in, if any: a package (``__init__.py``) or a
    folder of the repository other than problem2 holding source files (problem1, report)."""
    for path in (root, *root.parents):
        if path == REPOSITORY or not path.is_relative_to(REPOSITORY):
            return None
        if (path / "__init__.py").is_file():
            return path
        in_repository = path.parent == REPOSITORY and path != PROBLEM2
        if in_repository and (any(path.glob("*.py")) or any(path.glob("*.typ"))):
            return path
    return None


def foreign_entries(root: Path) -> list[str]:
    """The visible entries of folder ``root`` that no batch writes (the default folder also
    holds the studies)."""
    allowed = {*BATCH_ENTRIES, *(["studies"] if root == DEFAULT_OUTPUT_DIR.resolve() else [])}
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if p.name not in allowed and p.name[0] != ".")


def check_folder_kind(cfg: BatchConfig) -> None:
    """Refuse (SettingError on output_dir, naming the full path) a file, a folder inside the
    code, or a folder of other files: a batch goes into a new, empty or batch folder."""
    root = output_root(cfg)
    if root.exists() and not root.is_dir():
        raise SettingError("output_dir", f"must be a folder, not a file ({root})", cfg.output_dir)
    code = code_folder(root)
    if code is not None:
        problem = (
            f"is inside the code ({root} lies in {code}): choose a folder for results, "
            "e.g. --output_dir my_run from problem2/ or a folder under problem2/results/"
        )
        raise SettingError("output_dir", problem, cfg.output_dir)
    others = foreign_entries(root)
    if others:
        shown = ", ".join(others[:5]) + (", ..." if len(others) > 5 else "")
        problem = (
            f"holds files that are not a training batch's ({root}: {shown}); a batch goes into "
            "a new or empty folder or one holding a batch: choose another --output_dir"
        )
        raise SettingError("output_dir", problem, cfg.output_dir)


def check_output_dir(cfg: BatchConfig) -> None:
    """Refuse (SettingError on output_dir) before any work a folder that is not for a batch
    (:func:`check_folder_kind`, even with ``cfg.overwrite``), and, unless ``cfg.overwrite``,
    a folder where this batch would replace a batch with other settings, or non-default
    settings in the default folder. A batch with identical settings is replaced."""
    check_folder_kind(cfg)
    root = output_root(cfg)
    if cfg.overwrite:
        return
    remedy = f"choose another --output_dir, or pass --overwrite to replace the batch in {root}"
    new = batch_identity(cfg)
    manifest = root / "agent_models" / MANIFEST
    if manifest.is_file():
        try:
            differences = identity_differences(json.loads(manifest.read_text("utf-8")), new)
        except (OSError, ValueError, AttributeError):
            differences = ["its manifest.json is unreadable"]
        if differences:
            raise SettingError(
                "output_dir",
                f"holds a batch with other settings ({'; '.join(differences)}): {remedy}",
                cfg.output_dir,
            )
    is_default_folder = root == DEFAULT_OUTPUT_DIR.resolve()
    default_differences = identity_differences(batch_identity(BatchConfig()), new)
    if is_default_folder and default_differences:
        raise SettingError(
            "output_dir",
            "is the default results folder (the committed results of the default settings), "
            f"and these settings differ ({'; '.join(default_differences)}): {remedy}",
            cfg.output_dir,
        )
    if not manifest.is_file() and holds_results(root) and not is_default_folder:
        raise SettingError(
            "output_dir",
            f"holds results without a manifest.json (of an unknown batch): {remedy}",
            cfg.output_dir,
        )


# ------------------------------------------------------------------------------- one run
class SavingTrainer(DQNTrainer):
    """The learner, writing its agents as TorchScript policy files
    ``<mode>_seed<seed>_agent_{A,B}.pt`` (a study's agents may take another form:
    :meth:`export_agent`)."""

    def save_models(self, folder: Path | None = None) -> list[Path]:
        folder = self.models_dir if folder is None else folder
        return [
            self.export_agent(i, folder / f"{self.name}_agent_{a}.pt") for i, a in enumerate("AB")
        ]

    def export_agent(self, index: int, path: Path) -> Path:
        """Write agent ``index``: its network behind the mode's mask
        (:func:`~models.export_policy`)."""
        return export_policy(self.online.agent(index), self.mode, path)


def read_csv(path: Path) -> list[dict[str, float]]:
    with open(path, newline="", encoding="utf-8") as handle:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]


def train_one(
    cfg: BatchConfig,
    mode: str,
    seed: int,
    models_dir: Path,
    logs_dir: Path,
    trainer_class: type[DQNTrainer] = SavingTrainer,
    progress: Any = None,
) -> dict[str, Any]:
    """Train one (mode, seed) into ``models_dir`` / ``logs_dir``, run its selection evaluation
    (greedy and ε = 0.05 on ``cfg.final_eval_episodes`` validation episodes: what picks the
    best seed of a mode) and return it. ``progress.put((name, row, seconds))`` gets each row."""
    torch.set_num_threads(1)
    run_cfg = BatchConfig(
        **{**cfg.to_dict(), "mode": mode, "seed": seed, "seeds": [], "workers": 1}
        | {"output_dir": str(models_dir.parent)}
    )
    env = VectorMultiAgentEnv(  # the map: the trainer reads its grid, window and time limit
        1,
        grid_size=cfg.grid_shape(),
        max_steps=cfg.max_steps,
        seed=cfg.map_seed,
        reward_mode=cfg.reward_mode,
    )
    trainer = trainer_class(env, run_cfg)
    # train() appends each log row to its CSV file as it is measured and saves the models.
    trainer.models_dir, trainer.logs_dir = models_dir, logs_dir
    name = run_name(mode, seed)
    start = time.perf_counter()

    def report(row: dict[str, Any]) -> None:
        if progress is not None:
            progress.put((name, row, time.perf_counter() - start))
        if cfg.save_freq and row["env_steps"] % cfg.save_freq < cfg.eval_interval:
            trainer.save_models()

    trainer.train(report)
    selection: dict[str, Any] = {"select_by": cfg.select_by, "validation_seed": VALIDATION_SEED}
    for label, epsilon in (("greedy", 0.0), ("eps", EVAL_EPSILON)):
        summary = trainer.evaluation_summary(cfg.final_eval_episodes, epsilon, VALIDATION_SEED)
        selection[label] = {"epsilon": epsilon, **summary}
    write_json_atomic(logs_dir / f"{name}_selection.json", {"mode": mode, "seed": seed} | selection)
    return {"mode": mode, "seed": seed, **selection, "seconds": time.perf_counter() - start}


# ------------------------------------------------------------------------------ the batch
def run_experiments(
    cfg: BatchConfig, trainer_class: type[DQNTrainer] = SavingTrainer
) -> list[dict[str, Any]]:
    """Train every (mode, seed) of ``cfg`` in ``cfg.workers`` processes into a staging
    folder, then install it into ``cfg.output_dir`` (whole or not at all). Each run is a
    ``trainer_class`` (a study may pass a subclass of the learner).

    On KeyboardInterrupt the staging folder becomes ``<output_dir>/interrupted/`` (its CSV
    rows are what was measured) and the error is re-raised; on any other error it is
    deleted, with the output folder itself if this batch created it."""
    validated(cfg)
    check_output_dir(cfg)
    root = output_root(cfg)
    # The outermost folder that this batch creates (None: root exists).
    created = next((p for p in reversed((root, *root.parents)) if not p.exists()), None)
    for folder in (root, root / "agent_models", root / "training_logs"):
        remove_stale_temporaries(folder)
    staging = root / f".staging.{os.getpid()}"
    models_dir, logs_dir = staging / "agent_models", staging / "training_logs"
    try:
        shutil.rmtree(staging, ignore_errors=True)
        models_dir.mkdir(parents=True)
        logs_dir.mkdir()
        save_map(models_dir / "map.json", generate_map(cfg.grid_shape(), cfg.map_seed))
        write_json_atomic(models_dir / "hyperparameters.json", cfg.hyperparameters())
        jobs = [
            (cfg, m, s, models_dir, logs_dir, trainer_class)
            for m in cfg.run_modes()
            for s in cfg.run_seeds()
        ]
        finals = run_jobs(train_one, jobs, cfg.workers, ProgressLine(len(jobs), cfg.total_steps))
        write_batch_records(cfg, finals, models_dir, logs_dir)
        install(staging, root)
    except KeyboardInterrupt:  # keep what it measured (no manifest: no reader takes it for results)
        if staging.is_dir():
            shutil.rmtree(root / INTERRUPTED, ignore_errors=True)
            os.replace(staging, root / INTERRUPTED)
        raise
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if created and created.is_dir() and not any(p.is_file() for p in created.rglob("*")):
            shutil.rmtree(created, ignore_errors=True)  # it holds only empty folders
        raise
    return finals


def write_batch_records(
    cfg: BatchConfig, finals: list[dict[str, Any]], models_dir: Path, logs_dir: Path
) -> None:
    """After every run: timing, the best pair of each mode, the curves and (last) the manifest."""
    write_json_atomic(
        logs_dir / "timing.json",
        {run_name(f["mode"], f["seed"]): round(f.pop("seconds"), 1) for f in finals},
    )
    best = {}
    for mode in cfg.run_modes():
        runs = sorted((f for f in finals if f["mode"] == mode), key=lambda f: f["seed"])
        winner = runs[select_best([(f["greedy"], f["eps"]) for f in runs], cfg.select_by)]
        best[mode] = run_name(mode, winner["seed"])
        for agent in "AB":
            with temporary_path_for(models_dir / f"{mode}_agent_{agent}.pt") as temporary:
                shutil.copyfile(models_dir / f"{best[mode]}_agent_{agent}.pt", temporary)
    title = curves_title(cfg.hyperparameters())
    plot_training_curves(logs_dir, cfg.run_modes(), cfg.run_seeds(), title)
    write_json_atomic(models_dir / MANIFEST, manifest(cfg, finals, best, models_dir))


SELECTION_MEASURES = ("success_rate", "mean_steps_to_success", "mean_return")


def manifest(
    cfg: BatchConfig, finals: list[dict[str, Any]], best: dict[str, str], models_dir: Path
) -> dict[str, Any]:
    """The batch record that evaluate.py reads (format in the lead's CONTRACTS)."""
    runs = {}
    for final in finals:
        name = run_name(final["mode"], final["seed"])
        files = {agent: f"{name}_agent_{agent}.pt" for agent in "AB"}
        runs[name] = {
            "mode": final["mode"],
            "seed": final["seed"],
            **model_listing(files, models_dir),
            "selection": {"select_by": cfg.select_by}
            | {
                condition: {key: final[condition][key] for key in SELECTION_MEASURES}
                for condition in ("greedy", "eps")
            },
        }
        last = {agent: f"{LAST_WEIGHTS}/{name}_agent_{agent}.pt" for agent in "AB"}
        if all((models_dir / f).is_file() for f in last.values()):  # trained with keep_best
            runs[name]["last_weights"] = model_listing(last, models_dir)
    identity = {"format": 1, **batch_identity(cfg), "code_version": code_version()}
    return identity | {"runs": runs, "best": best}


def model_listing(files: dict[str, str], models_dir: Path) -> dict[str, dict[str, str]]:
    """The manifest's record of a model pair: files (relative to ``models_dir``), sha256."""
    digests = {a: hashlib.sha256((models_dir / f).read_bytes()) for a, f in files.items()}
    return {"models": files, "sha256": {a: d.hexdigest() for a, d in digests.items()}}


def code_version() -> str:
    """sha256 of the code of every module under problem2/ (the core, the batch machinery,
    analysis and studies; not results/), in path order: each file's relative path, a NUL
    byte, the dump of its syntax tree without docstrings, a NUL byte. Comments, docstrings
    and layout do not count, so a documentation edit leaves the version (and every
    manifest) as it is."""
    digest = hashlib.sha256()
    paths = [p for p in PROBLEM2.rglob("*.py") if "results" not in p.relative_to(PROBLEM2).parts]
    for path in sorted(paths, key=lambda p: p.relative_to(PROBLEM2).as_posix()):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):  # docstrings, also those after a dataclass field
            body = getattr(node, "body", None)
            if isinstance(body, list) and any(is_docstring(s) for s in body):
                node.body = [s for s in body if not is_docstring(s)] or [ast.Pass()]
        name = path.relative_to(PROBLEM2).as_posix()
        digest.update(name.encode("utf-8") + b"\0" + ast.dump(tree).encode() + b"\0")
    return digest.hexdigest()


def is_docstring(statement: ast.stmt) -> bool:
    """Whether ``statement`` is a string literal standing alone (a docstring)."""
    return (
        isinstance(statement, ast.Expr)
        and isinstance(statement.value, ast.Constant)
        and isinstance(statement.value.value, str)
    )


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
            f"removed {root / EVALUATION}: it evaluated the replaced batch; run evaluate.py "
            f"--checkpoint {root} for this one (in problem2/results: make problem2)"
        )
    for sub in ("training_logs", "agent_models"):
        if (root / sub).exists():
            replaced.mkdir(exist_ok=True)
            os.replace(root / sub, replaced / sub)
        os.replace(staging / sub, root / sub)
    shutil.rmtree(replaced, ignore_errors=True)
    shutil.rmtree(staging, ignore_errors=True)
    shutil.rmtree(root / INTERRUPTED, ignore_errors=True)  # superseded by a whole batch


# ------------------------------------------------------------------------------- figures
CURVE_PANELS = (
    ("eval_success_eps", "success rate", (0.0, 1.02)),
    ("eval_return_eps", "return ({reward})", None),
)  # validation episodes at ε = 0.05; {reward}: the batch's CURVE_REWARD_NAMES entry
CURVE_REWARD_NAMES = {  # reward_mode -> the short name the return axis carries
    "goal": "goal reward",
    "per_step": "assignment's reward",
    "arrival": "arrival reward",
}
CURVE_REWARDS = {  # reward_mode -> the reward the curves' return sums
    "goal": "goal reward (+10 when both agents stand on the target, −0.1 on every other step)",
    "per_step": "assignment's reward (+10 both on target, +2 per step one is on it, else −0.1)",
    "arrival": "arrival reward (+10 both on target, +2 when an agent first arrives, else −0.1)",
}


def curves_title(settings: dict[str, Any]) -> str:
    """The curves' title from a batch's hyperparameters: the map, and the settings that
    differ from the main experiment's reward and message learning."""
    return (
        f"Training progress on map seed {settings['map_seed']}"
        + (f" (reward {settings['reward_mode']})" if settings["reward_mode"] != "goal" else "")
        + (", untrained messages" if settings["comm_learning"] == "none" else "")
    )


def plot_training_curves(logs_dir: Path, modes: list[str], seeds: list[int], title: str) -> None:
    """Validation success and return (ε = 0.05) against env steps, one column per mode:
    every seed as a thin line (its last point is the weights the run ended with), the mean
    over seeds and the interquartile band; 6.5 in wide, as the report prints it. The reward
    summed is named from the batch's ``agent_models/hyperparameters.json``."""
    from matplotlib.figure import Figure  # here: a worker process never needs matplotlib
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter

    settings = json.loads((logs_dir.parent / "agent_models" / "hyperparameters.json").read_bytes())
    fig = Figure(figsize=(6.5, 4.9), layout="constrained")
    axes = np.asarray(fig.subplots(2, len(modes), sharex=True, sharey="row", squeeze=False))
    for column, mode in enumerate(modes):
        logs = [read_csv(logs_dir / f"{run_name(mode, seed)}.csv") for seed in seeds]
        length = min(len(log) for log in logs)
        steps = np.array([row["env_steps"] for row in logs[0][:length]])
        colour = MODE_COLOURS.get(mode)
        for ax, (key, label, limits) in zip(axes[:, column], CURVE_PANELS, strict=True):
            values = np.array([[row[key] for row in log[:length]] for log in logs])
            for run in values:
                ax.plot(steps, run, color=colour, alpha=0.35, linewidth=0.7)
            low, high = np.percentile(values, [25, 75], axis=0)
            ax.fill_between(steps, low, high, color=colour, alpha=0.25, linewidth=0)
            ax.plot(steps, values.mean(axis=0), color=colour, linewidth=2.0)
            if limits:
                ax.set_ylim(*limits)
            label = label.format(reward=CURVE_REWARD_NAMES[settings["reward_mode"]])
            ax.set_ylabel(label if column == 0 else "", fontsize=9)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=8)
            # "100k": full numbers would run into each other
            ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}k" if x else "0"))
        axes[0, column].set_title(f"{mode} ({len(seeds)} seeds)", fontsize=9)
        axes[1, column].set_xlabel("environment steps", fontsize=9)
    legend = [
        Line2D([], [], color="0.4", lw=0.7, label="one seed"),
        Line2D([], [], color="0.4", alpha=0.3, lw=7, label="interquartile range over seeds"),
        Line2D([], [], color="0.4", lw=2.0, label="mean over seeds"),
    ]
    fig.legend(handles=legend, loc="outside lower center", ncols=3, fontsize=8, frameon=False)
    reward = CURVE_REWARDS[settings["reward_mode"]]
    unseen = ", less the arrival term added for learning"
    words = f"Validation episodes at ε = 0.05; return: the {reward} summed over an episode"
    words += (
        " (the reward these agents learn from"
        + (unseen if settings["target_potential"] > 0 else "")
        + ")"
    )
    fig.suptitle(f"{title}\n{textwrap.fill(words + '.', width=100)}", fontsize=9)
    with temporary_path_for(logs_dir / "training_curves.png") as temporary:
        fig.savefig(temporary, format="png", dpi=150)
