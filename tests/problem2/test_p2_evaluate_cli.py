"""``python evaluate.py`` on tiny smoke-run models: every output file, agreement with the
trainer's own final evaluation, study discovery and clear errors for bad model files."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from analysis_runs import discover_experiments
from evaluate import MultiAgentEvaluator, load_trained_models, main
from multi_agent_env import MultiAgentEnv, load_map

from tests.conftest import PROBLEM2

TINY_RUN = [
    "--total_steps", "1536", "--num_envs", "16", "--learning_starts", "512",
    "--batch_size", "32", "--eval_interval", "512", "--eval_episodes", "16",
    "--final_eval_episodes", "32", "--buffer_size", "4096", "--num_seeds", "2",
    "--workers", "1",
]  # fmt: skip
OUTPUTS = [
    "performance.json",
    "comparison_table.md",
    "communication_analysis.json",
    "failure_analysis.json",
    "generalization.json",
    "trajectories.png",
    "comm_heatmap.png",
    "episode_independent.gif",
    "episode_comm.gif",
    "episode_full.gif",
]


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with tiny models of the three modes (seeds 641, 642), trained by train.py."""
    root = tmp_path_factory.mktemp("p2tiny")
    subprocess.run(
        [sys.executable, "train.py", *TINY_RUN, "--output_dir", str(root)],
        cwd=PROBLEM2,
        check=True,
        capture_output=True,
    )
    return root


@pytest.fixture(scope="module")
def evaluated(tiny_root: Path) -> tuple[dict, Path]:
    output = tiny_root / "evaluation_results"
    argv = ["--checkpoint", str(tiny_root / "agent_models"), "--num_episodes", "200"]
    return main(argv + ["--generalization_episodes", "40", "--render"]), output


def test_evaluate_writes_every_output(evaluated: tuple[dict, Path]) -> None:
    results, output = evaluated
    for name in OUTPUTS:
        assert (output / name).is_file() and (output / name).stat().st_size > 0, name
    assert not list(output.glob(".*tmp*"))  # atomic writes leave nothing behind
    performance = json.loads((output / "performance.json").read_text())
    main_entry = performance["experiments"]["main"]
    assert set(main_entry["modes"]) == {"independent", "comm", "full"}
    assert main_entry["baselines"]["oracle"]["success_rate"] == 1.0
    full = main_entry["modes"]["full"]
    assert full["seeds"] == [641, 642] and full["best_seed"] in (641, 642)
    for condition in ("greedy", "eps"):
        rate = full[condition]["success_rate"]
        assert rate["n"] == 2 and rate["ci95"][0] <= rate["mean"] <= rate["ci95"][1]
        assert set(full[condition]["failures"]) == {"swapping", "parked", "looping", "other"}
    assert results["performance"] == performance


def test_communication_analysis_has_causal_test_and_verdict(evaluated: tuple[dict, Path]) -> None:
    _, output = evaluated
    analysis = json.loads((output / "communication_analysis.json").read_text())
    modes = analysis["experiments"]["main"]["modes"]
    assert "causal" not in modes["independent"]
    for mode in ("comm", "full"):
        causal = modes[mode]["causal"]
        assert set(causal["eps"]) >= {"real", "shuffled", "zeroed", "real_minus_shuffled"}
        assert isinstance(causal["verdict"], str) and causal["verdict"]
        seed_entry = modes[mode]["per_seed"]["641"]
        assert set(seed_entry["messages"]) == {"A", "B"}
        assert set(seed_entry["correlations"]["A"]) == {
            "on_target", "sees_target", "target_distance", "agent_distance", "time_step"
        }  # fmt: skip
    generalization = json.loads((output / "generalization.json").read_text())
    assert list(generalization["maps"]) == [str(k) for k in range(10)]
    assert all(entry["oracle"]["success_rate"] == 1.0 for entry in generalization["maps"].values())


def test_evaluator_reproduces_the_trainers_final_greedy_evaluation(tiny_root: Path) -> None:
    models = tiny_root / "agent_models"
    final = json.loads((tiny_root / "training_logs" / "full_seed641_final.json").read_text())
    env = MultiAgentEnv(grid=load_map(models / "map.json"))
    evaluator = MultiAgentEvaluator(env, *load_trained_models(models, "full", seed=641))
    results = evaluator.run(final["greedy"]["episodes"], epsilon=0.0)
    assert results.successes.mean() == final["greedy"]["success_rate"]
    assert results.returns.mean() == pytest.approx(final["greedy"]["mean_return"], rel=1e-6)


def test_render_prints_the_episode_step_by_step(tiny_root: Path, capsys) -> None:
    models = tiny_root / "agent_models"
    env = MultiAgentEnv(grid=load_map(models / "map.json"))
    reward, success, info = MultiAgentEvaluator(env, *load_trained_models(models)).run_episode(
        render=True
    )
    printed = capsys.readouterr().out
    assert f"step {info['steps']}/50" in printed and "actions A" in printed
    assert ("success" if success else "failure") in printed.splitlines()[-1]
    assert isinstance(reward, float) and isinstance(success, bool)


def test_message_shuffling_cannot_matter_to_independent_agents(tiny_root: Path) -> None:
    models = tiny_root / "agent_models"
    env = MultiAgentEnv(grid=load_map(models / "map.json"))
    evaluator = MultiAgentEvaluator(env, *load_trained_models(models, "independent"))
    real = evaluator.run(100, 0.05, record=False)
    for condition in ("shuffled", "zeroed"):
        changed = evaluator.run(100, 0.05, condition, record=False)
        assert np.array_equal(real.returns, changed.returns)


def test_studies_are_discovered_with_their_labels(tiny_root: Path, tmp_path: Path) -> None:
    shutil.copytree(tiny_root / "agent_models", tmp_path / "agent_models")
    study = tmp_path / "studies" / "no_dial" / "agent_models"
    shutil.copytree(tiny_root / "agent_models", study)
    settings = json.loads((study / "hyperparameters.json").read_text())
    (study / "hyperparameters.json").write_text(json.dumps(settings | {"comm_learning": "none"}))
    panel = tmp_path / "studies" / "map_panel" / "map3" / "agent_models"
    panel.mkdir(parents=True)
    for path in (tiny_root / "agent_models").glob("full_seed641_*"):
        shutil.copy(path, panel)
    experiments = discover_experiments(tmp_path / "agent_models")
    assert [e.name for e in experiments] == ["main", "no_dial", "map_panel/map3"]
    assert experiments[1].label("comm") == "comm (message untrained (no DIAL))"
    assert experiments[2].seeds == {"full": [641]}
    assert np.array_equal(experiments[2].grid, experiments[0].grid)  # defaults: map seed 641


def test_missing_or_corrupt_model_files_are_named(tiny_root: Path, tmp_path: Path) -> None:
    models = tmp_path / "agent_models"
    shutil.copytree(tiny_root / "agent_models", models)
    (models / "comm_seed642_agent_B.pt").unlink()
    with pytest.raises(FileNotFoundError, match="comm_seed642_agent_B.pt"):
        main(["--checkpoint", str(models), "--num_episodes", "10"])
    (models / "full_agent_A.pt").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="full_agent_A.pt"):
        load_trained_models(models, "full")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_trained_models(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="no trained models"):
        main(["--checkpoint", str(tmp_path)])
