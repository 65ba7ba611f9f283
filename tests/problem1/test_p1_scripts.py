"""train.py, visualize.py and the stochasticity study write every promised file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import PROBLEM1, load_problem_module

FIGURES = ("value_heatmap.png", "policy_arrows.png", "q_functions.png", "convergence.png")


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("p1results")
    completed = subprocess.run(
        [
            sys.executable,
            "train.py",
            "--max-iter",
            "1000",
            "--mc_episodes",
            "500",
            "--results-dir",
            str(out),
        ],
        cwd=PROBLEM1,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert completed.returncode == 0, completed.stderr
    return out


def test_train_writes_arrays_summary_and_figures(trained: Path) -> None:
    values = np.load(trained / "value_function.npz")
    assert values["values"].shape == (25,) and int(values["iterations"]) == len(values["history"])
    assert np.load(trained / "q_function.npz")["q_values"].shape == (25, 4)
    policy = np.load(trained / "optimal_policy.npz")["policy"]
    assert policy.shape == (25,) and policy.dtype == np.int64
    for name in FIGURES:
        assert (trained / "visualizations" / name).stat().st_size > 10_000


def test_summary_reports_convergence_and_verification(trained: Path) -> None:
    summary = json.loads((trained / "summary.json").read_text())
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


def test_visualize_results_redraws_from_saved_files(trained: Path) -> None:
    from visualize import visualize_results

    for name in FIGURES:
        (trained / "visualizations" / name).unlink()
    written = visualize_results(trained)
    assert set(FIGURES) <= set(written)
    assert all((trained / "visualizations" / name).exists() for name in FIGURES)


def test_visualize_results_names_the_missing_file(tmp_path: Path) -> None:
    from visualize import visualize_results

    with pytest.raises(FileNotFoundError, match="value_function.npz is missing"):
        visualize_results(tmp_path)


def test_reruns_write_identical_files(trained: Path, tmp_path: Path) -> None:
    train = load_problem_module("problem1", "train")
    train.main(["--mc_episodes", "500", "--results_dir", str(tmp_path)])
    for name in ("value_function.npz", "q_function.npz", "optimal_policy.npz"):
        assert (tmp_path / name).read_bytes() == (trained / name).read_bytes()
    for name in FIGURES:
        png = "visualizations/" + name
        assert (tmp_path / png).read_bytes() == (trained / png).read_bytes()
    assert not list(tmp_path.glob(".*tmp*")), "temporary files left behind"


def test_stochasticity_study(tmp_path: Path) -> None:
    study = load_problem_module("problem1", "stochasticity_study").main(
        ["--results_dir", str(tmp_path)]
    )
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
    saved = json.loads((tmp_path / "stochasticity_study.json").read_text())
    assert saved["settings"][2]["v_start"] == pytest.approx(reference["v_start"])
    for name in ("stochasticity_policies.png", "stochasticity_start_value.png"):
        assert (tmp_path / "visualizations" / name).stat().st_size > 10_000
