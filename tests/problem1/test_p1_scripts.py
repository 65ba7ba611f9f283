"""train.py, visualize.py and the stochasticity study: promised files, byte-identical reruns,
a whole result set or none, and a console that is not UTF-8."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import PROBLEM1, ROOT, load_problem_module

FIGURES = ("value_heatmap.png", "policy_arrows.png", "q_functions.png", "convergence.png")
ARRAYS = ("value_function.npz", "q_function.npz", "optimal_policy.npz")
# ε and → do not exist in cp1252: printing them to such a console fails unless it is made safe
UNICODE_FOLDER = "out-ε→"


def run_script(script: str, *args: str, cwd: Path = PROBLEM1) -> subprocess.CompletedProcess:
    """Run a Problem 1 script as a user on a Windows (cp1252) console would."""
    return subprocess.run(
        [sys.executable, str(PROBLEM1 / script), *args],
        cwd=cwd,
        capture_output=True,
        env={**os.environ, "PYTHONIOENCODING": "cp1252", "MPLBACKEND": "Agg"},
        timeout=300,
        check=False,
    )


def result_files(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("p1results") / UNICODE_FOLDER
    completed = run_script(
        "train.py", "--max-iter", "1000", "--mc_episodes", "500", "--results-dir", str(out)
    )
    assert completed.returncode == 0, completed.stderr.decode("cp1252", "replace")
    assert b"results written to" in completed.stdout
    return out


def test_train_writes_arrays_summary_and_figures(trained: Path) -> None:
    values = np.load(trained / "value_function.npz")
    assert values["values"].shape == (25,) and int(values["iterations"]) == len(values["history"])
    assert np.load(trained / "q_function.npz")["q_values"].shape == (25, 4)
    policy = np.load(trained / "optimal_policy.npz")["policy"]
    assert policy.shape == (25,) and policy.dtype == np.int64
    for name in (*FIGURES, "comparison.png", "convergence.svg"):
        assert (trained / "visualizations" / name).stat().st_size > 10_000
    assert not [p.name for p in trained.rglob(".*")], "temporary files or folders left behind"


def test_summary_reports_convergence_and_verification(trained: Path) -> None:
    summary = json.loads((trained / "summary.json").read_text(encoding="utf-8"))
    assert summary["value_iteration"]["iterations"] == len(
        np.load(trained / "value_function.npz")["history"]
    )
    assert summary["value_iteration"]["converged"] and summary["q_iteration"]["converged"]
    assert summary["policies_agree"] is True
    assert summary["verification"]["within_bound"] is True
    assert summary["verification"]["monte_carlo"]["episodes"] == 500
    assert summary["v_start"] == pytest.approx(
        float(np.load(trained / "value_function.npz")["values"][0])
    )
    timing = json.loads((trained / "timing.json").read_text(encoding="utf-8"))
    assert timing["run_id"] == summary["run_id"]
    for solver in ("value_iteration", "q_iteration"):
        assert timing[solver]["seconds_per_sweep"] > 0
        assert "wall_time_s" not in summary[solver]


def test_every_array_file_carries_the_run_id(trained: Path) -> None:
    summary = json.loads((trained / "summary.json").read_text(encoding="utf-8"))
    for name in ARRAYS:
        assert str(np.load(trained / name)["run_id"]) == summary["run_id"]


def test_no_result_file_holds_an_absolute_path(trained: Path) -> None:
    for name, content in result_files(trained).items():
        for folder in (trained, ROOT, Path.home()):
            assert str(folder).encode("utf-8") not in content, name


def test_reruns_write_identical_files(trained: Path, tmp_path: Path) -> None:
    """Every file but timing.json is the same bytes, whatever the folder or working directory."""
    out = tmp_path / "elsewhere"
    completed = run_script(
        "train.py", "--mc_episodes", "500", "--results_dir", str(out), cwd=tmp_path
    )
    assert completed.returncode == 0
    first, second = result_files(trained), result_files(out)
    assert set(first) == set(second)
    changed = [name for name in first if first[name] != second[name]]
    assert changed in ([], ["timing.json"])


def test_train_accepts_both_flag_spellings() -> None:
    train = load_problem_module("problem1", "train")
    assert train.parse_args(["--max_iter", "7"]).max_iter == 7
    assert train.parse_args(["--max-iter", "9"]).max_iter == 9
    defaults = train.parse_args([])
    assert (defaults.seed, defaults.gamma, defaults.epsilon, defaults.max_iter) == (
        641,
        0.95,
        1e-4,
        1000,
    )


def test_visualize_redraws_from_saved_files_on_a_cp1252_console(trained: Path) -> None:
    for name in FIGURES:
        (trained / "visualizations" / name).unlink()
    completed = run_script("visualize.py", "--results_dir", str(trained))
    assert completed.returncode == 0, completed.stderr.decode("cp1252", "replace")
    assert all((trained / "visualizations" / name).exists() for name in FIGURES)


def test_visualize_results_names_the_missing_file(tmp_path: Path) -> None:
    from visualize import visualize_results

    with pytest.raises(FileNotFoundError, match="value_function.npz is missing"):
        visualize_results(tmp_path)


def test_visualize_cli_says_what_is_missing_without_a_traceback(tmp_path: Path) -> None:
    completed = run_script("visualize.py", "--results_dir", str(tmp_path))
    assert completed.returncode == 1
    error = completed.stderr.decode("cp1252", "replace")
    assert "value_function.npz is missing" in error and "Traceback" not in error


def test_arrays_of_different_runs_are_refused(trained: Path, tmp_path: Path) -> None:
    from visualize import visualize_results

    train = load_problem_module("problem1", "train")
    train.main(["--gamma", "0.5", "--mc_episodes", "2", "--results_dir", str(tmp_path)])
    # train.main drew the figures from its own arrays: one run is fine.
    shutil.copy(trained / "q_function.npz", tmp_path / "q_function.npz")  # gamma 0.95
    with pytest.raises(ValueError, match="do not come from one train.py run"):
        visualize_results(tmp_path)


def test_an_interrupted_run_leaves_the_previous_results_untouched(
    trained: Path, tmp_path: Path, monkeypatch
) -> None:
    train = load_problem_module("problem1", "train")
    out = tmp_path / "results"
    shutil.copytree(trained, out)
    before = result_files(out)

    def interrupted(folder: Path) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(train, "visualize_results", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train.main(["--gamma", "0.5", "--mc_episodes", "2", "--results_dir", str(out)])
    assert result_files(out) == before
    assert not list(out.glob(".*"))


def test_stale_temporary_files_are_removed_at_start(trained: Path, tmp_path: Path) -> None:
    out = tmp_path / "results"
    shutil.copytree(trained, out)
    stale = [
        out / ".value_function.tmp4242.npz",
        out / "visualizations" / ".convergence.tmp4242.png",
        out / ".staging4242" / "summary.json",
    ]
    for path in stale:
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(b"half-written")
    from visualize import main as visualize_main

    visualize_main(["--results_dir", str(out)])
    assert not list(out.rglob(".*"))


@pytest.mark.parametrize("script", ["train.py", "visualize.py", "stochasticity_study.py"])
def test_help_prints_usage_with_defaults_and_writes_nothing(script: str, tmp_path: Path) -> None:
    out = tmp_path / "never"
    completed = run_script(script, "--results_dir", str(out), "--help")
    assert completed.returncode == 0
    text = completed.stdout.decode("cp1252")
    assert text.startswith("usage:") and "--results_dir" in text and "(default:" in text
    assert not out.exists()


def test_train_help_shows_every_default() -> None:
    text = run_script("train.py", "--help").stdout.decode("cp1252")
    for default in ("641", "0.95", "0.0001", "1000", "10000"):
        assert f"(default: {default})" in text


@pytest.mark.parametrize(
    ("script", "args", "message"),
    [
        ("train", ["--epsilon", "inf"], "expected a finite number"),
        ("train", ["--epsilon", "0"], "must be a finite number > 0"),
        ("train", ["--gamma", "1"], "must lie in [0, 1)"),
        ("train", ["--gamma", "nan"], "expected a finite number"),
        ("train", ["--mc_episodes", "1"], "must be an integer >= 2"),
        ("train", ["--mc_episodes", "0"], "must be an integer >= 2"),
        ("train", ["--mc_episodes", "-5"], "must be an integer >= 2"),
        ("train", ["--max_iter", "0"], "must be an integer >= 1"),
        ("train", ["--max_iter", "2.5"], "expected an integer"),
        ("train", ["--seed", "-1"], "must be an integer >= 0"),
        ("stochasticity_study", ["--epsilon", "inf"], "expected a finite number"),
        ("stochasticity_study", ["--gamma", "-0.5"], "must lie in [0, 1)"),
    ],
)
def test_bad_flags_are_usage_errors_naming_the_flag(script, args, message, tmp_path, capsys):
    module = load_problem_module("problem1", script)
    with pytest.raises(SystemExit) as exit_info:
        module.main([*args, "--results_dir", str(tmp_path / "out")])
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith("usage:") and f"argument {args[0]}" in error and message in error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("script", ["train", "visualize", "stochasticity_study"])
def test_results_dir_must_not_be_a_file(script: str, tmp_path: Path, capsys) -> None:
    a_file = tmp_path / "notes.txt"
    a_file.write_text("not a folder", encoding="utf-8")
    for target in (a_file, a_file / "results"):
        with pytest.raises(SystemExit):
            load_problem_module("problem1", script).main(["--results_dir", str(target)])
        error = capsys.readouterr().err
        assert "argument --results_dir" in error and "notes.txt is a file, not a folder" in error
    assert a_file.read_text(encoding="utf-8") == "not a folder"


def test_stochasticity_study(tmp_path: Path) -> None:
    out = tmp_path / UNICODE_FOLDER
    completed = run_script("stochasticity_study.py", "--results_dir", str(out))
    assert completed.returncode == 0, completed.stderr.decode("cp1252", "replace")
    study = json.loads((out / "stochasticity_study.json").read_text(encoding="utf-8"))
    settings = study["settings"]
    assert [s["drift"] for s in settings] == [0.0, 0.05, 0.1, 0.15, 0.2, 0.3]
    start_values = [s["v_start"] for s in settings]
    assert start_values == sorted(start_values, reverse=True)  # noise only costs value
    assert settings[0]["v_start"] == pytest.approx(
        sum(-0.1 * 0.95**t for t in range(7)) + 10 * 0.95**7, abs=1e-3
    )
    assert settings[0]["expected_steps"] == pytest.approx(8.0)
    assert settings[0]["detour_states"] == []
    reference = next(s for s in settings if s["drift"] == 0.1)
    assert reference["iterations"] > settings[0]["iterations"]
    assert reference["v_start"] == pytest.approx(4.905474846680396, abs=1e-8)
    for name in (
        "stochasticity_policies.png",
        "stochasticity_start_value.png",
        "stochasticity_start_value.svg",
    ):
        assert (out / "visualizations" / name).stat().st_size > 10_000
    first = result_files(out)
    assert run_script("stochasticity_study.py", "--results_dir", str(out)).returncode == 0
    assert result_files(out) == first  # byte-identical rerun
    assert not list(out.rglob(".*"))
