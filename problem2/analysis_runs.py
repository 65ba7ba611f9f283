"""Finding and loading what training produced: the experiments under a results root, their
maps and settings, and the exported TorchScript model pairs (loaded with
``torch.jit.load`` only, through :func:`models.load_policy`).

Layout of an experiment root (written by ``train.py``):
``agent_models/<mode>_seed<seed>_agent_{A,B}.pt``, ``agent_models/<mode>_agent_{A,B}.pt``
(the best seed), ``agent_models/map.json``, ``agent_models/hyperparameters.json``.
Study roots (same layout) live under ``<root>/studies/``: ``per_step``, ``no_dial`` and
``map_panel/map<K>``.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from grid_maps import DEFAULT_MAP_SEED, generate_map, load_map
from models import OBSERVATION_DIM, load_policy

PROBLEM2 = Path(__file__).resolve().parent
DEFAULT_ROOT = PROBLEM2 / "results"
MODES = ("independent", "comm", "full")
NUM_ACTIONS = 5
SEED_FILE = re.compile(r"^(independent|comm|full)_seed(\d+)_agent_A\.pt$")
DEFAULT_SETTINGS = {
    "map_seed": DEFAULT_MAP_SEED,
    "grid_size": 10,
    "max_steps": 50,
    "reward_mode": "arrival",
    "comm_learning": "dial",
}


@dataclass
class Experiment:
    """One training root: its map, settings and the (mode, seed) model pairs found."""

    name: str  # "main", "per_step", "no_dial" or "map_panel/map<K>"
    models_dir: Path
    settings: dict
    grid: np.ndarray
    seeds: dict[str, list[int]] = field(default_factory=dict)  # mode -> seeds, sorted

    def label(self, mode: str) -> str:
        """Row label of ``mode`` in tables, e.g. ``full (per_step reward)``."""
        extras = []
        if self.settings.get("reward_mode", "arrival") != "arrival":
            extras.append(f"{self.settings['reward_mode']} reward")
        if mode != "independent" and self.settings.get("comm_learning", "dial") != "dial":
            extras.append("message untrained (no DIAL)")
        return f"{mode} ({', '.join(extras)})" if extras else mode


def study_model_dirs(checkpoint_dir: Path) -> list[tuple[str, Path]]:
    """(name, agent_models folder) of the main experiment (``checkpoint_dir`` itself) and
    of every study that may exist under ``<checkpoint_dir>/../studies``."""
    studies = checkpoint_dir.parent / "studies"
    candidates = [("main", checkpoint_dir), ("per_step", studies / "per_step" / "agent_models")]
    candidates.append(("no_dial", studies / "no_dial" / "agent_models"))
    panel = studies / "map_panel"
    if panel.is_dir():
        maps = [p for p in panel.iterdir() if re.fullmatch(r"map\d+", p.name)]
        for path in sorted(maps, key=lambda p: int(p.name[3:])):
            candidates.append((f"map_panel/{path.name}", path / "agent_models"))
    return candidates


def read_experiment(name: str, models_dir: Path) -> Experiment | None:
    """The experiment in ``models_dir`` (None if it holds no seed model files).

    Settings come from ``hyperparameters.json`` (defaults of the main experiment where it
    is missing) and the map from ``map.json`` (else drawn from the settings' map seed)."""
    found: dict[str, list[int]] = {}
    for path in models_dir.glob("*_seed*_agent_A.pt") if models_dir.is_dir() else []:
        if match := SEED_FILE.match(path.name):
            found.setdefault(match[1], []).append(int(match[2]))
    if not found:
        return None
    settings = dict(DEFAULT_SETTINGS)
    hyperparameters = models_dir / "hyperparameters.json"
    if hyperparameters.is_file():
        try:
            settings |= json.loads(hyperparameters.read_text())
        except json.JSONDecodeError as error:
            raise ValueError(f"{hyperparameters}: not valid JSON ({error})") from error
    map_file = models_dir / "map.json"
    size = int(settings["grid_size"])
    grid = (
        load_map(map_file)
        if map_file.is_file()
        else generate_map((size, size), int(settings["map_seed"]))
    )
    seeds = {mode: sorted(found[mode]) for mode in MODES if mode in found}
    return Experiment(name, models_dir, settings, grid, seeds)


def discover_experiments(checkpoint_dir: Path = DEFAULT_ROOT / "agent_models") -> list[Experiment]:
    """Every experiment with model files: the main one in ``checkpoint_dir``, then the
    studies beside it (see :func:`study_model_dirs`); those without models are skipped."""
    experiments = []
    for name, models_dir in study_model_dirs(Path(checkpoint_dir)):
        if (experiment := read_experiment(name, models_dir)) is not None:
            experiments.append(experiment)
    return experiments


def model_paths(models_dir: Path, mode: str, seed: int | None = None) -> tuple[Path, Path]:
    """Files of agents A and B: the best pair of ``mode`` (``seed`` None) or one seed's."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {MODES}")
    stem = mode if seed is None else f"{mode}_seed{seed}"
    return models_dir / f"{stem}_agent_A.pt", models_dir / f"{stem}_agent_B.pt"


def load_checked_policy(path: Path) -> torch.jit.ScriptModule:
    """Load one exported policy and check that it maps observations [B, 11] to
    (Q-values [B, 5], message [B, 1] in [0, 1]); errors name the file."""
    model = load_policy(path)  # FileNotFoundError / ValueError naming the file
    try:
        with torch.inference_mode():
            q_values, message = model(torch.zeros(2, OBSERVATION_DIM))
    except Exception as error:  # a TorchScript module with another signature
        raise ValueError(
            f"{path}: the model does not accept observations [B, 11]: {error}"
        ) from error
    if tuple(q_values.shape) != (2, NUM_ACTIONS) or tuple(message.shape) != (2, 1):
        raise ValueError(
            f"{path}: expected outputs (Q-values [B, 5], message [B, 1]), got "
            f"{tuple(q_values.shape)} and {tuple(message.shape)}"
        )
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
    """The seed whose files the best pair of ``mode`` copies (None if no seed matches)."""
    best_A, best_B = model_paths(experiment.models_dir, mode)
    if not (best_A.is_file() and best_B.is_file()):
        return None
    content = best_A.read_bytes(), best_B.read_bytes()
    for seed in experiment.seeds.get(mode, []):
        path_A, path_B = model_paths(experiment.models_dir, mode, seed)
        if (path_A.read_bytes(), path_B.read_bytes()) == content:
            return seed
    return None
