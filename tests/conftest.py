"""Shared test set-up.

The graders import each problem's modules from inside its folder (``cd problem1``),
so both problem folders go on ``sys.path``, problem2 first. Only ``train`` exists in both;
load it with :func:`load_problem_module`: problem1's under its own module name, problem2's
as ``train`` (the name its studies import and its worker processes unpickle).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import matplotlib
import torch

matplotlib.use("Agg")

ROOT = Path(__file__).resolve().parent.parent
PROBLEM1 = ROOT / "problem1"
PROBLEM2 = ROOT / "problem2"
for folder in (PROBLEM1, PROBLEM2):
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))

# As every entry point does, ask for MKL's reproducible code path before the first matrix
# product, so tests compute the same bytes as the committed runs (and as their workers).
importlib.import_module("safety").use_reproducible_matmul()


def load_problem_module(problem: str, name: str) -> ModuleType:
    """Import ``<problem>/<name>.py`` under the unique name ``<problem>_<name>`` (problem2's
    under its own name: its folder is first on the path)."""
    if problem == "problem2":
        return importlib.import_module(name)
    unique = f"{problem}_{name}"
    if unique in sys.modules:
        return sys.modules[unique]
    spec = importlib.util.spec_from_file_location(unique, ROOT / problem / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[unique] = module
    spec.loader.exec_module(module)
    return module


def weights_of(module: torch.nn.Module) -> torch.Tensor:
    """All of ``module``'s parameters as one detached vector (a copy)."""
    return torch.nn.utils.parameters_to_vector(module.parameters()).detach().clone()
