"""Finding and loading what training produced: the experiments under a results root, their
maps and settings, and the exported TorchScript model pairs (loaded with
``torch.jit.load`` only, through :func:`load_policy`).

Layout of an experiment root (written by ``train.py``):
``agent_models/<mode>_seed<seed>_agent_{A,B}.pt``, ``agent_models/<mode>_agent_{A,B}.pt``
(the best seed), ``agent_models/map.json``, ``agent_models/hyperparameters.json``.
Study roots (same layout) live under ``<root>/studies/``: ``per_step`` and ``no_dial``
(found by ``analysis.pipeline.discover_experiments``; the map panel's batches under
``studies/panel/`` are evaluated by ``studies/panel.py``).

A batch written by ``train.py`` carries ``agent_models/manifest.json`` (modes, seeds, map,
hyperparameters, the sha256 of every model file). Where it exists, exactly its runs are
evaluated: a listed file that is missing or whose sha256 differs, and a model file that it
does not list, are errors naming the file. Without a manifest the model files found are
evaluated (``Experiment.manifest`` is then None, and ``evaluate.py`` says so).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from rollout import EVAL_EPSILON
from vector_env import DEFAULT_MAP_SEED, MASKED_INPUTS, OBSERVATION_DIM, check_grid, generate_map

PROBLEM2 = Path(__file__).resolve().parent.parent
DEFAULT_ROOT = PROBLEM2 / "results"
DEFAULT_CHECKPOINT = DEFAULT_ROOT / "agent_models"
EPISODES_RANGE = (1, 5000)  # of every --*episodes flag
MODES = tuple(MASKED_INPUTS)  # independent, comm, distance, full
NUM_ACTIONS = 5
SEED_FILE = re.compile(r"^(independent|comm|distance|full)_seed(\d+)_agent_A\.pt$")
MANIFEST = "manifest.json"
PROBE_ROWS = 256  # observations each loaded model is checked on before any evaluation
DEFAULT_SETTINGS = {
    "map_seed": DEFAULT_MAP_SEED,
    "grid_size": 10,
    "max_steps": 50,
    "reward_mode": "goal",
    "comm_learning": "dial",
}


def load_map(path: str | Path) -> np.ndarray:
    """Read a map written by ``batch.plumbing.save_map``; ValueError (naming the file) if it is
    invalid."""
    try:
        content = json.loads(Path(path).read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from error
    if not isinstance(content, dict) or "grid" not in content:
        raise ValueError(f"{path}: expected a JSON object with a 'grid' list of rows")
    try:
        return check_grid(content["grid"])
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from error


def load_policy(path: str | Path) -> torch.jit.ScriptModule:
    """Load a policy written by ``models.export_policy`` (needs only ``torch.jit.load``).

    Raises FileNotFoundError if ``path`` does not exist, ValueError if it is not a
    TorchScript module."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy file at {path}")
    try:
        with warnings.catch_warnings():  # torch 2.13 deprecates it; the course requires it
            warnings.filterwarnings(
                "ignore", r"`torch\.jit\.load` is deprecated", DeprecationWarning
            )
            policy = torch.jit.load(str(path), map_location="cpu")
    except Exception as error:  # torch raises RuntimeError or zipfile/pickle errors
        raise ValueError(f"{path} is not a valid TorchScript policy: {error}") from error
    return policy.eval()


@dataclass
class Experiment:
    """One training root: its map, settings and the (mode, seed) model pairs found."""

    name: str  # "main", "per_step", "no_dial" (or a study's own name, e.g. "panel/map<K>")
    models_dir: Path
    settings: dict
    grid: np.ndarray
    seeds: dict[str, list[int]] = field(default_factory=dict)  # mode -> seeds, sorted
    manifest: dict | None = None  # the batch manifest, None if the folder has none
    best: dict[str, int] = field(default_factory=dict)  # mode -> seed of the best pair

    def label(self, mode: str) -> str:
        """Row label of ``mode`` in tables, e.g. ``full (per_step reward)``."""
        extras = []
        if self.settings.get("reward_mode", "goal") != "goal":
            extras.append(f"{self.settings['reward_mode']} reward")
        if mode != "independent" and self.settings.get("comm_learning", "dial") != "dial":
            extras.append("message untrained (no DIAL)")
        return f"{mode} ({', '.join(extras)})" if extras else mode


def sha256_of(path: Path) -> str:
    """Hex sha256 of the file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def relative_models_dir(name: str) -> str:
    """The agent_models folder of experiment ``name`` relative to the results root (as
    ``analysis.pipeline.study_model_dirs`` lays them out), for outputs that must hold no
    absolute path."""
    return "agent_models" if name == "main" else f"studies/{name}/agent_models"


def experiment_info(experiment: Experiment) -> dict:
    """What an evaluation's files say of ``experiment``: its settings, models folder (relative
    to the results root), map, target, and whether a manifest listed its models."""
    info = {
        key: experiment.settings.get(key)
        for key in ("map_seed", "reward_mode", "comm_learning", "max_steps")
    }
    info |= {"models_dir": relative_models_dir(experiment.name), "grid": experiment.grid.tolist()}
    info["manifest"] = experiment.manifest is not None
    info["target"] = [int(v) for v in np.argwhere(experiment.grid == 2)[0]]
    return info


def read_manifest(models_dir: Path) -> dict | None:
    """The batch manifest of ``models_dir`` (None if there is none); ValueError naming the
    file if it is not valid JSON of the expected form."""
    path = Path(models_dir) / MANIFEST
    if not path.is_file():
        return None
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
        runs = manifest["runs"]
        for name, run in runs.items():
            if run["mode"] not in MODES or not isinstance(run["seed"], int):
                raise ValueError(f"run {name}: unknown mode or non-integer seed")
            for agent in "AB":
                run["models"][agent], run["sha256"][agent]  # noqa: B018 (presence check)
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError, ValueError) as error:
        raise ValueError(f"{path}: not a valid batch manifest ({error!r})") from error
    return manifest


def _check_manifest_files(models_dir: Path, manifest: dict) -> dict[str, int]:
    """Check every model file of ``models_dir`` against ``manifest``; return mode -> seed of
    the best pair. Errors name the file: missing, changed since training (sha256) or not
    listed (a model of another batch)."""
    expected: dict[str, str] = {}
    for run in manifest["runs"].values():
        for agent in "AB":
            expected[run["models"][agent]] = run["sha256"][agent]
            if "last_weights" in run:  # the run's final weights, in a subfolder
                last = run["last_weights"]
                expected[last["models"][agent]] = last["sha256"][agent]
    best: dict[str, int] = {}
    for mode, run_name in (manifest.get("best") or {}).items():
        run = manifest["runs"].get(run_name)
        if run is None:
            raise ValueError(f"{models_dir / MANIFEST}: best run {run_name!r} is not listed")
        best[mode] = run["seed"]
        for agent in "AB":
            if (models_dir / f"{mode}_agent_{agent}.pt").exists():
                expected[f"{mode}_agent_{agent}.pt"] = run["sha256"][agent]
    for name, digest in sorted(expected.items()):
        path = models_dir / name
        if not path.is_file():
            raise FileNotFoundError(f"{path}: listed in {MANIFEST} but missing")
        if sha256_of(path) != digest:
            raise ValueError(
                f"{path}: damaged or replaced (its sha256 differs from {MANIFEST}); "
                "retrain or restore the file"
            )
    unlisted = sorted(p.name for p in models_dir.glob("*.pt") if p.name not in expected)
    if unlisted:
        raise ValueError(
            f"{models_dir}: model files not listed in {MANIFEST} (another batch's?): "
            f"{', '.join(unlisted)}; remove them or retrain into a fresh folder"
        )
    return best


def _settings_and_grid(models_dir: Path, manifest: dict | None) -> tuple[dict, np.ndarray]:
    settings = dict(DEFAULT_SETTINGS)
    hyperparameters = models_dir / "hyperparameters.json"
    if manifest is not None:
        settings |= manifest.get("hyperparameters", {})
        settings |= {k: manifest[k] for k in ("map_seed", "reward_mode") if k in manifest}
    elif hyperparameters.is_file():
        try:
            settings |= json.loads(hyperparameters.read_text(encoding="utf-8"))
        except json.JSONDecodeError as error:
            raise ValueError(f"{hyperparameters}: not valid JSON ({error})") from error
    size = settings["grid_size"]
    rows, cols = (size, size) if isinstance(size, int) else (size[0], size[-1])
    map_file = models_dir / "map.json"
    grid = (
        load_map(map_file)
        if map_file.is_file()
        else generate_map((int(rows), int(cols)), int(settings["map_seed"]))
    )
    return settings, grid


def read_experiment(name: str, models_dir: Path) -> Experiment | None:
    """The experiment in ``models_dir`` (None if it holds no manifest and no seed model
    files).

    With a manifest: its runs, settings and best pairs, every file checked (see the module
    docstring). Without: the ``<mode>_seed<seed>_agent_A.pt`` files found, settings from
    ``hyperparameters.json`` (the main experiment's defaults where missing). The map comes
    from ``map.json``, else it is drawn from the settings' map seed and grid size."""
    models_dir = Path(models_dir)
    manifest = read_manifest(models_dir) if models_dir.is_dir() else None
    found: dict[str, list[int]] = {}
    best: dict[str, int] = {}
    if manifest is not None:
        best = _check_manifest_files(models_dir, manifest)
        for run in manifest["runs"].values():
            found.setdefault(run["mode"], []).append(run["seed"])
    else:
        for path in models_dir.glob("*_seed*_agent_A.pt") if models_dir.is_dir() else []:
            if match := SEED_FILE.match(path.name):
                found.setdefault(match[1], []).append(int(match[2]))
    if not found:
        return None
    settings, grid = _settings_and_grid(models_dir, manifest)
    seeds = {mode: sorted(found[mode]) for mode in MODES if mode in found}
    return Experiment(name, models_dir, settings, grid, seeds, manifest, best)


def resolve_checkpoint(path: Path) -> tuple[Path, str | None]:
    """The agent_models folder named by ``--checkpoint`` (relative paths against the current
    folder) and a note if it was found inside a run folder; ValueError saying what is
    wrong (missing, a file, no models)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(missing_folder(path))
    if not path.is_dir():
        hint = f" (did you mean {path.parent}?)" if path.suffix == ".pt" else ""
        raise ValueError(
            f"--checkpoint {path} is a file; give the agent_models folder that holds the "
            f"model files{hint}"
        )
    has_models = (path / MANIFEST).is_file() or any(path.glob("*_seed*_agent_A.pt"))
    if not has_models and (path / "agent_models").is_dir():
        return path / "agent_models", f"using {path / 'agent_models'} (the run folder's models)"
    if not has_models:
        raise ValueError(
            f"--checkpoint {path}: no trained models (no {MANIFEST}, no "
            "<mode>_seed<seed>_agent_A.pt); run train.py first"
        )
    return path, None


def missing_folder(path: Path) -> str:
    """The error for a ``--checkpoint`` folder that does not exist: the full path looked at,
    and the folder meant if the path exists relative to problem2/ instead."""
    message = f"--checkpoint {path}: no such folder {path.resolve()}"
    if path.is_absolute():
        return message
    message += f" (relative paths start at the current folder, {Path.cwd().resolve()})"
    beside = PROBLEM2 / path
    if beside.exists():
        message += f"; did you mean {beside}? run evaluate.py from {PROBLEM2}"
    return message


def model_paths(models_dir: Path, mode: str, seed: int | None = None) -> tuple[Path, Path]:
    """Files of agents A and B: the best pair of ``mode`` (``seed`` None) or one seed's."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {MODES}")
    stem = mode if seed is None else f"{mode}_seed{seed}"
    return models_dir / f"{stem}_agent_A.pt", models_dir / f"{stem}_agent_B.pt"


def probe_observations(obs_dim: int = OBSERVATION_DIM, rows: int = PROBE_ROWS) -> torch.Tensor:
    """Observations [rows, obs_dim] a policy may meet: patches of -1/0/1/2, messages and
    distances in [0, 1] (the first row all zeros, as at an episode's start). Seeded."""
    rng = np.random.default_rng(0)
    obs = rng.integers(-1, 3, size=(rows, obs_dim)).astype(np.float32)
    obs[:, -2:] = rng.random((rows, 2))
    obs[0] = 0.0
    return torch.from_numpy(obs)


def check_policy_outputs(
    q_values: torch.Tensor | np.ndarray, messages: torch.Tensor | np.ndarray, name: str
) -> None:
    """ValueError naming ``name`` unless the Q-values are finite and the messages finite
    numbers in [0, 1] (the sigmoid output the assignment asks for)."""
    q_values, messages = np.asarray(q_values), np.asarray(messages)
    if not np.isfinite(q_values).all():
        raise ValueError(f"{name}: the model outputs non-finite Q-values (NaN or inf)")
    if not (messages.min() >= 0.0 and messages.max() <= 1.0):  # False for NaN too
        low, high = float(np.nanmin(messages)), float(np.nanmax(messages))
        raise ValueError(
            f"{name}: the model's message must be a sigmoid output in [0, 1], got values in "
            f"[{low:.3g}, {high:.3g}]{' and NaN' if np.isnan(messages).any() else ''}"
        )


def check_policy(model: torch.nn.Module, name: str, obs_dim: int = OBSERVATION_DIM) -> None:
    """Check that ``model`` maps observations [B, obs_dim] to (Q-values [B, 5], message
    [B, 1] in [0, 1]), finite, on :func:`probe_observations`; errors name ``name``."""
    probe = probe_observations(obs_dim)
    try:
        with torch.inference_mode():
            q_values, message = model(probe)
    except Exception as error:  # a module with another signature
        raise ValueError(
            f"{name}: the model does not accept observations [B, {obs_dim}]: {error}"
        ) from error
    if tuple(q_values.shape) != (len(probe), NUM_ACTIONS) or tuple(message.shape) != (
        len(probe),
        1,
    ):
        raise ValueError(
            f"{name}: expected outputs (Q-values [B, 5], message [B, 1]), got "
            f"{tuple(q_values.shape)} and {tuple(message.shape)}"
        )
    check_policy_outputs(q_values, message, name)


def load_checked_policy(path: Path) -> torch.jit.ScriptModule:
    """Load one exported policy and :func:`check_policy` it; errors name the file."""
    model = load_policy(path)  # FileNotFoundError / ValueError naming the file
    check_policy(model, str(path))
    return model


def load_model_pair(
    models_dir: Path, mode: str, seed: int | None = None
) -> tuple[torch.jit.ScriptModule, torch.jit.ScriptModule]:
    """Load (model_A, model_B) of ``mode`` (best pair, or ``seed``) from ``models_dir``."""
    models_dir = Path(models_dir)
    if not models_dir.is_dir():
        raise FileNotFoundError(f"checkpoint directory {models_dir} does not exist")
    path_A, path_B = model_paths(models_dir, mode, seed)
    return load_checked_policy(path_A), load_checked_policy(path_B)


def best_seed(experiment: Experiment, mode: str) -> int | None:
    """The seed of the best pair of ``mode``: from the manifest, else the seed whose files
    the best pair copies (None if there is no best pair). A best pair that matches no seed
    file is an error naming it (damaged or from another run)."""
    if mode in experiment.best:
        return experiment.best[mode]
    best_A, best_B = model_paths(experiment.models_dir, mode)
    if not (best_A.is_file() or best_B.is_file()):
        return None
    for path in (best_A, best_B):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing (its partner file exists)")
    content = best_A.read_bytes(), best_B.read_bytes()
    for seed in experiment.seeds.get(mode, []):
        path_A, path_B = model_paths(experiment.models_dir, mode, seed)
        if (path_A.read_bytes(), path_B.read_bytes()) == content:
            return seed
    load_checked_policy(best_A), load_checked_policy(best_B)  # a damaged file is named here
    raise ValueError(
        f"{best_A} / {best_B}: the best {mode} pair matches no {mode}_seed<seed> pair of "
        f"{experiment.models_dir} (replaced or left from another run)"
    )


def make_parser(description: str, prog: str | None = None) -> argparse.ArgumentParser:
    """The flags ``python evaluate.py`` and ``python -m analysis.pipeline`` share."""
    parser = argparse.ArgumentParser(
        prog=prog,
        allow_abbrev=False,
        description=description,
        epilog="Relative paths are resolved against the current folder.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--checkpoint",
        "--checkpoint_dir",
        "--checkpoint-dir",
        type=Path,
        default=DEFAULT_CHECKPOINT,
        help="agent_models folder of the main experiment, or the run folder holding it "
        "(relative to the current folder; the default is this package's "
        "results/agent_models, from any folder). With a manifest.json exactly its runs are "
        "evaluated, every file checked against it; without one, the model files found are",
    )
    parser.add_argument(
        "--num_episodes",
        "--num-episodes",
        type=int,
        default=1000,
        help="test episodes per trained seed and condition",
    )
    parser.add_argument(
        "--epsilon",
        type=float,
        default=EVAL_EPSILON,
        help="exploration rate of the ε-greedy condition",
    )
    parser.add_argument(
        "--output_dir",
        "--output-dir",
        type=Path,
        default=None,
        help="output folder; None: evaluation_results beside the agent_models folder",
    )
    return parser


def checked_args(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """``parser``'s flags, each in its range (else a usage error naming the flag and the
    range), ``checkpoint`` resolved to the agent_models folder."""
    args = parser.parse_args(argv)
    low, high = EPISODES_RANGE
    for flag, value in vars(args).items():
        if flag.endswith("episodes") and not low <= value <= high:
            parser.error(f"--{flag} must be an integer in {low}..{high}, got {value}")
    if not 0 <= args.epsilon <= 1:
        parser.error(f"--epsilon must lie in [0, 1], got {args.epsilon}")
    try:
        args.checkpoint, note = resolve_checkpoint(args.checkpoint)
    except ValueError as error:
        parser.error(str(error))
    if note:
        print(note)
    return args
