"""Runtime code may import only torch, numpy, matplotlib and the standard library; the
report's build script only typst and the standard library."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RUNTIME_DIRS = ("problem1", "problem2", "report")
ALLOWED_THIRD_PARTY = {"torch", "numpy", "matplotlib", "mpl_toolkits"}
REPORT_THIRD_PARTY = {"typst"}


def runtime_files() -> list[Path]:
    return sorted(p for d in RUNTIME_DIRS for p in (ROOT / d).rglob("*.py"))


def imported_top_level_modules(path: Path) -> list[tuple[int, str]]:
    """(line, top-level module) for every absolute import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name.split(".")[0]) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module.split(".")[0]))
    return found


def test_there_is_runtime_code_to_check() -> None:
    assert any(p.parent.name == "problem1" for p in runtime_files())


def problem_folder(path: Path) -> Path:
    """The folder a runtime file's imports resolve from: its top-level folder under ROOT
    (problem2/analysis/x.py imports core modules and sibling packages from problem2/), or
    its own folder outside ROOT."""
    try:
        return ROOT / path.relative_to(ROOT).parts[0]
    except ValueError:
        return path.parent


def forbidden_imports(path: Path) -> list[str]:
    """Imports of ``path`` that are neither allowed libraries nor sibling modules."""
    folder = problem_folder(path)
    local_modules = {p.stem for p in folder.glob("*.py")}
    local_modules |= {p.parent.name for p in folder.glob("*/__init__.py")}
    third_party = REPORT_THIRD_PARTY if path.parent.name == "report" else ALLOWED_THIRD_PARTY
    allowed = third_party | local_modules | set(sys.stdlib_module_names)
    return [
        f"line {line}: {mod}"
        for line, mod in imported_top_level_modules(path)
        if mod not in allowed
    ]


@pytest.mark.parametrize("path", runtime_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_runtime_module_imports_only_allowed_libraries(path: Path) -> None:
    assert forbidden_imports(path) == [], f"{path.name} imports forbidden modules"


def test_checker_flags_forbidden_imports(tmp_path: Path) -> None:
    (tmp_path / "helper.py").write_text("")
    sample = tmp_path / "sample.py"
    sample.write_text(
        "import os\nimport numpy as np\nimport torch.nn\nimport helper\n"
        "from scipy import stats\nimport gymnasium as gym\nfrom tqdm.auto import tqdm\n"
    )
    assert forbidden_imports(sample) == ["line 5: scipy", "line 6: gymnasium", "line 7: tqdm"]
