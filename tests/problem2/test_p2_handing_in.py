"""What a student meets on the way to handing in: a run that cannot make one update, an
abbreviated flag, a folder that is not for a batch or lies inside the code, an evaluation of
a replaced batch, a checkpoint looked for in the wrong folder, and Python without .venv: each
stops before any work with a message naming the input and the fix."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import output_folder
import pytest
from analysis.pipeline import discover_experiments
from analysis.runs import resolve_checkpoint
from settings import DEFAULT_OUTPUT_DIR, SettingError, TrainConfig, validated

from tests.conftest import PROBLEM1, PROBLEM2, ROOT, load_problem_module

train = load_problem_module("problem2", "train")
TINY = "--mode full --seeds 1 --num_envs 16 --learning_starts 512 --batch_size 32 --workers 1"


def refusal(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The usage error of ``train.py argv`` (exit status 2), as printed."""
    with pytest.raises(SystemExit) as stop:
        train.main(argv)
    assert stop.value.code == 2
    return capsys.readouterr().err


# ------------------------------------------------------------------ runs that cannot learn
@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"total_steps": 1000}, "total_steps"),  # below learning_starts 5000
        ({"total_steps": 4999}, "total_steps"),
        ({"num_episodes": 10}, "num_episodes"),  # 64 copies x 50 steps: at most 3200 steps
        ({"num_episodes": 64}, "num_episodes"),
        ({"num_episodes": 20, "num_envs": 4, "max_steps": 50}, "num_episodes"),  # 250 < 5000
    ],
)
def test_a_budget_that_ends_before_the_first_update_is_refused(settings, field) -> None:
    with pytest.raises(SettingError) as error:
        validated(TrainConfig(**settings))
    assert error.value.name == field
    assert "learning_starts 5000" in error.value.problem and "no update" in error.value.problem


@pytest.mark.parametrize(
    "settings",
    [
        {"total_steps": 5000},
        {"num_episodes": 65},  # two rounds of 64 episodes may take 6400 env steps
        {"total_steps": 1000, "learning_starts": 1000},
        {"num_episodes": 10, "learning_starts": 500},
        {"total_steps": 10, "num_episodes": 100},  # an episode budget replaces total_steps
    ],
)
def test_a_budget_that_reaches_the_first_update_is_accepted(settings) -> None:
    assert validated(TrainConfig(**settings)) is not None


def test_the_command_line_names_the_flag_and_the_fix_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    argv = ["--mode", "full", "--seeds", "641", "--output_dir", str(out)]
    message = refusal([*argv, "--total_steps", "1000"], capsys)
    assert "argument --total_steps: must be at least learning_starts 5000" in message
    assert "raise --total_steps or lower --learning_starts, got 1000" in message
    message = refusal([*argv, "--num_episodes", "10"], capsys)
    assert "argument --num_episodes:" in message and "use at least 65 episodes" in message
    assert not out.exists()


def test_abbreviated_flags_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    message = refusal(["--total_step", "10", "--output_dir", str(tmp_path / "x")], capsys)
    assert "unrecognized arguments: --total_step" in message
    problem1_train = load_problem_module("problem1", "train")
    with pytest.raises(SystemExit):
        problem1_train.parse_args(["--max_it", "5"])
    assert "unrecognized arguments: --max_it" in capsys.readouterr().err


def parser_calls_without_allow_abbrev() -> list[str]:
    """Every ``ArgumentParser(...)`` call in the code that does not pass allow_abbrev=False."""
    found = []
    folders = (PROBLEM1, PROBLEM2, ROOT / "report", ROOT / "bench")
    for path in (p for folder in folders for p in folder.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            called = getattr(node, "func", None)
            if getattr(called, "attr", getattr(called, "id", None)) != "ArgumentParser":
                continue
            keywords = {k.arg: k.value for k in node.keywords}
            flag = keywords.get("allow_abbrev")
            if not (isinstance(flag, ast.Constant) and flag.value is False):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


def test_every_parser_refuses_abbreviations() -> None:
    assert parser_calls_without_allow_abbrev() == []


def test_each_flag_states_its_default_once() -> None:
    for action in train.build_parser()._actions:
        assert (action.help or "").count("(default:") <= 1, action.dest
    workers = next(a for a in train.build_parser()._actions if a.dest == "workers")
    assert workers.help.endswith("(default: the available cores)")


# ------------------------------------------------------------------ where a batch may go
def check_output_dir(cfg: TrainConfig) -> None:
    """The folder rule as train.py applies it to ``cfg``."""
    root = Path(cfg.output_dir).resolve()
    default = TrainConfig().identity()
    output_folder.check_output_dir(root, cfg.identity(), cfg.overwrite, DEFAULT_OUTPUT_DIR, default)


def test_a_folder_inside_the_code_is_refused_even_with_overwrite(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(PROBLEM2)
    for folder, flags in (("analysis", []), ("analysis/new_run", ["--overwrite"])):
        message = refusal([*TINY.split(), "--output_dir", folder, *flags], capsys)
        code = "is the code folder problem2/analysis" if "/" not in folder else ""
        within = "lies in the code folder problem2/analysis" if "/" in folder else ""
        assert f"argument --output_dir: {code or within}:" in message
        assert "choose a folder for results" in message
    assert not (PROBLEM2 / "analysis" / "new_run").exists()
    named = {
        "../report": "is the code folder report",
        "../problem1/results/x": "lies in the code folder problem1",
        ".": "is the code folder problem2",
        "..": "is the repository's root",
    }
    for folder, words in named.items():
        with pytest.raises(output_folder.FolderError, match=words):
            check_output_dir(TrainConfig(output_dir=folder, overwrite=True))


def test_a_folder_of_other_files_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "my documents"
    folder.mkdir()
    (folder / "thesis.txt").write_text("mine", encoding="utf-8")
    for flags in ([], ["--overwrite"]):
        message = refusal([*TINY.split(), "--output_dir", str(folder), *flags], capsys)
        assert f"holds files that are not a training batch's ({folder}: thesis.txt)" in message
        assert "choose another --output_dir" in message
    assert sorted(p.name for p in folder.iterdir()) == ["thesis.txt"]


@pytest.mark.parametrize("entries", [[], ["agent_models", "training_logs", "evaluation_results"]])
def test_a_new_empty_or_batch_folder_is_accepted(tmp_path: Path, entries: list[str]) -> None:
    for name in entries:
        (tmp_path / "run" / name).mkdir(parents=True)
    check_output_dir(TrainConfig(output_dir=str(tmp_path / "run"), overwrite=True))
    check_output_dir(TrainConfig(output_dir=str(tmp_path / "new" / "run")))
    default = TrainConfig()  # the committed results folder, its studies beside the batch
    check_output_dir(default)


# ---------------------------------------------------------- an evaluation goes with its batch
def fake_batch(folder: Path, digest: str) -> None:
    """agent_models/ with a manifest listing one run of checksum ``digest``, training_logs/."""
    (folder / "agent_models").mkdir(parents=True)
    (folder / "training_logs").mkdir()
    runs = {"full_seed1": {"sha256": {"A": digest, "B": digest}}}
    manifest = folder / "agent_models" / output_folder.MANIFEST
    manifest.write_text(json.dumps({"runs": runs}), encoding="utf-8")


def test_replacing_a_batch_removes_the_evaluation_of_the_old_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "my_run"
    fake_batch(root, "old")
    (root / "evaluation_results").mkdir()
    (root / "evaluation_results" / "performance.json").write_text("{}", encoding="utf-8")
    fake_batch(root / ".staging.1", "new")
    output_folder.install(root / ".staging.1", root)
    assert sorted(p.name for p in root.iterdir()) == ["agent_models", "training_logs"]
    assert "new" in (root / "agent_models" / output_folder.MANIFEST).read_text(encoding="utf-8")
    assert f"removed {root / 'evaluation_results'}" in capsys.readouterr().out


def test_an_evaluation_of_byte_identical_models_stays(tmp_path: Path) -> None:
    root = tmp_path / "my_run"
    fake_batch(root, "same")
    (root / "evaluation_results").mkdir()
    fake_batch(root / ".staging.1", "same")
    output_folder.install(root / ".staging.1", root)
    assert sorted(p.name for p in root.iterdir()) == [
        "agent_models",
        "evaluation_results",
        "training_logs",
    ]


# ------------------------------------------------------------------ wrong folder, no .venv
def test_a_missing_checkpoint_names_the_full_path_and_the_folder_meant(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError) as error:
        resolve_checkpoint(Path("my_run"))
    assert f"no such folder {tmp_path.resolve() / 'my_run'}" in str(error.value)
    with pytest.raises(ValueError) as error:
        resolve_checkpoint(Path("results"))  # exists in problem2/, not here
    assert f"did you mean {PROBLEM2 / 'results'}? run evaluate.py from {PROBLEM2}" in str(
        error.value
    )


@pytest.mark.parametrize(
    ("folder", "command", "missing"),
    [
        (PROBLEM2, ["train.py"], "numpy, torch, matplotlib not found"),
        (PROBLEM2, ["evaluate.py", "--help"], "numpy, torch, matplotlib not found"),
        (PROBLEM2, ["-m", "analysis.baselines"], "numpy, torch, matplotlib not found"),
        (PROBLEM2, ["-m", "analysis.training_curves"], "numpy, torch, matplotlib not found"),
        (PROBLEM1, ["train.py"], "numpy, matplotlib not found"),
        (PROBLEM1, ["visualize.py"], "numpy, matplotlib not found"),
        (PROBLEM1, ["stochasticity_study.py"], "numpy, matplotlib not found"),
    ],
)
def test_without_the_virtual_environment_a_command_says_what_to_do(
    folder: Path, command: list[str], missing: str
) -> None:
    # -S: no site-packages, as a Python outside .venv without the pinned packages.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    result = subprocess.run(
        [sys.executable, "-S", *command], cwd=folder, capture_output=True, text=True, env=env
    )
    assert result.returncode == 1
    assert missing in result.stderr and "source .venv/bin/activate" in result.stderr
    assert "Traceback" not in result.stderr


# ------------------------------------------------------------------ the committed results
def test_the_committed_models_folder_holds_its_batches_only() -> None:
    """``make`` evaluates results/agent_models: a stray model file (one in no manifest, e.g.
    from a run by hand) makes evaluate.py refuse the folder, so a fresh clone's make fails."""
    experiments = discover_experiments(PROBLEM2 / "results" / "agent_models")
    assert experiments and all(e.manifest is not None for e in experiments)
    assert {"independent", "comm", "full"} <= set(experiments[0].seeds)
