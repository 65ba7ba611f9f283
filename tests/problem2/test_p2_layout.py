"""The house: imports flow one way (studies -> analysis -> core), problem2 and the tests are
laid out by ``ruff format`` alone, and the default update is the autograd one that a reader
finds in ``trainer.td_loss``."""

from __future__ import annotations

import ast
import re
import tokenize
from pathlib import Path

import pytest
import torch

from tests.conftest import PROBLEM2, ROOT, load_problem_module

train = load_problem_module("problem2", "train")
SUBFOLDERS = ("analysis", "studies", "batch")
# The course's scripts that may reach into a subfolder: the trainer runs batches, the
# evaluator uses the analysis' evaluator, loaders and figures.
COURSE_ENTRY_SCRIPTS = {"train.py": set(), "evaluate.py": {"analysis"}}
# Modules and code lines (non-blank, non-comment; docstrings count) of the learner's import
# closure: what a student reads for the DQN in one sitting. Its settings module declares each
# setting with its check (one declaration instead of two lists): 6 modules, about 1,870 lines
# (was 7 / 1,395 with the checks in a second list outside it).
LEARNER_BUDGET = (6, 1900)
# The same of ``python evaluate.py``: what a student reads to follow the course's evaluation.
EVALUATE_BUDGET = (12, 2400)
# What only the report's analyses (``python -m analysis.pipeline``) need.
REPORT_ONLY = ("pipeline", "outputs", "report", "interventions", "information", "stats")
REPORT_ONLY += ("generalization", "held_out", "estimate_plots", "baselines", "arrivals")
STUDY_EXTENSIONS = ("map_pool", "share_weights", "prioritized", "dueling", "coverage_bonus")
STUDY_EXTENSIONS += ("on_target_bonus", "memory")


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute imports, ``from x import y`` also as x.y)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found |= {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}
    return found


def top_packages(path: Path) -> set[str]:
    return {name.split(".")[0] for name in imported_modules(path)}


def import_closure(start: str) -> dict[str, Path]:
    """The problem2 modules that ``start`` imports, directly or not."""
    seen: dict[str, Path] = {}
    todo = [start]
    while todo:
        name = todo.pop()
        parts = name.split(".")
        candidates = [PROBLEM2.joinpath(*parts).with_suffix(".py")]
        candidates.append(PROBLEM2.joinpath(*parts, "__init__.py"))
        path = next((p for p in candidates if p.exists()), None)
        if name in seen or path is None:
            continue
        seen[name] = path
        todo += sorted(imported_modules(path))
    return seen


@pytest.mark.parametrize("path", sorted(PROBLEM2.glob("*.py")), ids=lambda p: p.name)
def test_core_modules_import_no_subfolder(path: Path) -> None:
    allowed = COURSE_ENTRY_SCRIPTS.get(path.name, set())
    assert top_packages(path) & set(SUBFOLDERS) <= allowed


@pytest.mark.parametrize("path", sorted((PROBLEM2 / "analysis").glob("*.py")), ids=lambda p: p.name)
def test_analysis_imports_no_study(path: Path) -> None:
    assert "studies" not in top_packages(path)


def test_the_checker_sees_subfolder_imports(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("from analysis.stats import x\nimport studies.reward_study\n")
    assert top_packages(sample) >= {"analysis", "studies"}


def test_train_py_needs_only_the_core() -> None:
    closure = import_closure("train")
    assert "trainer" in closure and "replay" in closure
    assert not [name for name in closure if name.split(".")[0] in ("analysis", "studies")]
    assert len(closure) <= 9, sorted(closure)  # the learner's 8 and train.py itself


def test_evaluate_py_reads_alone() -> None:
    """``python evaluate.py``'s closure: within EVALUATE_BUDGET, without batch machinery,
    training settings, studies or the report's analyses."""
    closure = import_closure("evaluate")
    modules, lines = EVALUATE_BUDGET
    assert len(closure) <= modules, sorted(closure)
    assert sum(code_lines(path) for path in closure.values()) <= lines
    assert "analysis.evaluator" in closure and "multi_agent_env" in closure
    for name in closure:
        assert name.split(".")[0] not in ("batch", "studies", "settings", "train_config"), name
        assert name.removeprefix("analysis.") not in REPORT_ONLY, name


def code_lines(path: Path) -> int:
    """Non-blank lines that are not comments (docstrings count)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return sum(1 for line in lines if line.strip() and not line.strip().startswith("#"))


def identifiers(path: Path) -> set[str]:
    """Names used as code (not words in docstrings), and strings that are identifiers."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute | ast.keyword | ast.arg):
            names.add(getattr(node, "attr", None) or getattr(node, "arg", None))
        elif isinstance(node, ast.FunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            names.add(node.value)
    return names


def test_the_learner_is_a_small_core_without_batch_machinery_or_study_extensions() -> None:
    """The module that defines td_loss and everything it imports: within LEARNER_BUDGET,
    none from a subfolder, no branch for a study extension."""
    closure = import_closure("trainer")
    modules, lines = LEARNER_BUDGET
    assert len(closure) <= modules, sorted(closure)
    assert sum(code_lines(path) for path in closure.values()) <= lines
    assert all(path.parent == PROBLEM2 for path in closure.values()), sorted(closure)
    for name, path in closure.items():
        assert not set(STUDY_EXTENSIONS) & identifiers(path), name


def test_problem2_root_holds_the_course_files_and_a_small_core() -> None:
    assert len(list(PROBLEM2.glob("*.py"))) <= 12


def formatter_escapes(path: Path) -> list[int]:
    """Lines of ``path`` with a comment that turns ``ruff format`` off (fmt: skip / off)."""
    with path.open(encoding="utf-8") as source:
        return [
            token.start[0]
            for token in tokenize.generate_tokens(source.readline)
            if token.type == tokenize.COMMENT and re.search(r"fmt:\s*(skip|off)\b", token.string)
        ]


def test_the_escape_checker_reads_comments_not_strings(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text('x = [1,  2]  # fmt: skip\ntext = "# fmt: off"\n# fmt: off\n', "utf-8")
    assert formatter_escapes(sample) == [1, 3]


def test_problem2_and_tests_are_laid_out_by_the_formatter_alone() -> None:
    """No formatter escape anywhere in problem2/ (core, analysis, studies) or tests/."""
    files = sorted([*PROBLEM2.rglob("*.py"), *(ROOT / "tests").rglob("*.py")])
    assert len(files) > 50 and PROBLEM2 / "trainer.py" in files
    escapes = [
        f"{path.relative_to(ROOT)}:{line}" for path in files for line in formatter_escapes(path)
    ]
    assert escapes == []


def test_every_default_update_runs_backward(tmp_path: Path, monkeypatch) -> None:
    """A short run at the default settings: one autograd backward() per gradient update."""
    calls = []
    original = torch.Tensor.backward

    def counted(self: torch.Tensor, *args, **kwargs) -> None:
        calls.append(1)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(torch.Tensor, "backward", counted)
    cfg = train.validated(
        train.TrainConfig(
            mode="full",
            seed=3,
            total_steps=3_000,
            learning_starts=1_000,
            eval_interval=3_000,
            eval_episodes=4,
            output_dir=str(tmp_path),
        )
    )
    env = load_problem_module("problem2", "multi_agent_env").MultiAgentEnv(seed=641)
    trainer = train.MultiAgentTrainer(env, cfg)
    trainer.train()
    assert trainer.updates > 0 and len(calls) == trainer.updates
