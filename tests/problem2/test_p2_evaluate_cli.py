"""``python evaluate.py`` and ``python -m analysis.pipeline`` on tiny smoke-run models: every
output file, the course's three files as the pipeline writes them in full, study discovery,
the batch manifest, clear errors for bad model files and paths, a cp1252 console, and the
course interface used as a grader would (defaults, plain networks)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import evaluate as evaluate_module
import numpy as np
import pytest
import torch
from analysis import baselines, pipeline
from analysis.baselines import POLICIES
from analysis.episodes import model_policy
from analysis.evaluator import experiment_evaluator
from analysis.failures import FAILURE_KINDS
from analysis.generalization import models_on_maps
from analysis.information import MEASURES
from analysis.interventions import INTERVENTIONS, intervention_test
from analysis.pipeline import discover_experiments
from analysis.runs import best_seed, load_map, sha256_of
from evaluate import (
    MultiAgentEvaluator,
    create_evaluation_report,
    load_trained_models,
    main,
    parse_args,
)
from models import AgentDQN, DuelingDQN, export_policy
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_SEED, run_episodes
from vector_env import VectorMultiAgentEnv

from tests.conftest import PROBLEM2, load_problem_module

TINY_RUN_FLAGS = (
    "--total_steps 1536 --num_envs 16 --learning_starts 512 --batch_size 32 --eval_interval 512 "
    "--eval_episodes 16 --final_eval_episodes 32 --buffer_size 4096 --num_seeds 2 --workers 1"
)
TINY_RUN = TINY_RUN_FLAGS.split()
EPISODES = 200  # test episodes per seed and condition in the ``evaluated`` run
OUTPUTS = [
    "performance.json",
    "comparison_table.md",
    "communication_analysis.json",
    "interventions.json",
    "interventions.csv",
    "interventions.png",
    "communication_measures.json",
    "communication_measures.csv",
    "failure_decomposition.csv",
    "mode_differences.csv",
    "held_out.csv",
    "failure_decomposition.png",
    "communication_measures.png",
    "failure_analysis.json",
    "generalization.json",
    "trajectories.png",
    "trajectories.json",
    "comm_heatmap.png",
    "episode_independent.gif",
    "episode_comm.gif",
    "episode_full.gif",
]


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with tiny models of the three modes (seeds 641, 642), trained by train.py (in
    this process: train.py's own subprocess runs are tested in test_p2_cli.py)."""
    root = tmp_path_factory.mktemp("p2tiny")
    load_problem_module("problem2", "train").main([*TINY_RUN, "--output_dir", str(root)])
    return root


@pytest.fixture(scope="module")
def evaluated(tiny_root: Path) -> tuple[dict, Path]:
    """The report's evaluation (``python -m analysis.pipeline``) of the tiny models."""
    output = tiny_root / "evaluation_results"
    argv = ["--checkpoint", str(tiny_root), "--num_episodes", str(EPISODES)]  # the run folder
    return pipeline.main(argv + ["--generalization_episodes", "10"]), output


@pytest.fixture(scope="module")
def course_run(tiny_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """``python evaluate.py`` of the same models, into a folder of its own."""
    output = tmp_path_factory.mktemp("course") / "evaluation_results"
    argv = ["--checkpoint", str(tiny_root), "--num_episodes", str(EPISODES)]
    return main(argv + ["--output_dir", str(output), "--render"]), output


COURSE_FILES = ("performance.json", "communication_analysis.json", "trajectories.png")


def leaves(data: object, path: tuple = ()) -> dict[tuple, object]:
    """Every value of nested dicts that is not a dict, by its path of keys."""
    if not isinstance(data, dict):
        return {path: data}
    return {k: v for key, value in data.items() for k, v in leaves(value, (*path, key)).items()}


def test_evaluate_writes_the_course_files(course_run: tuple[dict, Path]) -> None:
    """evaluate.py writes the assignment's three files, and only those: each mode's success
    greedy and ε-greedy per seed and the mean over seeds, and what the messages say."""
    results, output = course_run
    assert sorted(p.name for p in output.iterdir()) == sorted(COURSE_FILES)
    performance = json.loads((output / "performance.json").read_text("utf-8"))
    assert results["performance"] == performance
    full = performance["experiments"]["main"]["modes"]["full"]
    assert full["seeds"] == [641, 642] and full["best_seed"] in (641, 642)
    for condition in ("greedy", "eps"):
        rate = full[condition]["success_rate"]
        per_seed = [full["per_seed"][str(s)][condition]["success_rate"] for s in (641, 642)]
        assert rate["per_seed"] == per_seed and rate["mean"] == pytest.approx(np.mean(per_seed))
        assert set(full["per_seed"]["641"][condition]["failures"]) >= set(FAILURE_KINDS)
    analysis = json.loads((output / "communication_analysis.json").read_text("utf-8"))
    assert set(analysis["experiments"]["main"]["modes"]["comm"]["per_seed"]["641"]) == {
        "messages",
        "correlations",
    }


def test_the_pipeline_writes_the_course_files_in_full(
    course_run: tuple[dict, Path], evaluated: tuple[dict, Path], tiny_root: Path, capsys
) -> None:
    """Every number evaluate.py writes stands at the same place in the pipeline's files, the
    figure has the same bytes; evaluate.py run on the pipeline's folder keeps its JSON files
    and rewrites the figure byte for byte."""
    _, course = course_run
    _, output = evaluated
    for name in COURSE_FILES[:2]:
        part = leaves(json.loads((course / name).read_text("utf-8")))
        full = leaves(json.loads((output / name).read_text("utf-8")))
        assert part and all(full.get(path, ()) == value for path, value in part.items()), name
    assert (course / "trajectories.png").read_bytes() == (output / "trajectories.png").read_bytes()
    before = {name: (output / name).read_bytes() for name in COURSE_FILES}
    main(["--checkpoint", str(tiny_root), "--num_episodes", str(EPISODES)])
    assert "performance.json: the file there holds every number" in capsys.readouterr().out
    assert {name: (output / name).read_bytes() for name in COURSE_FILES} == before


def test_the_pipeline_writes_every_output(evaluated: tuple[dict, Path]) -> None:
    results, output = evaluated
    for name in OUTPUTS:
        assert (output / name).is_file() and (output / name).stat().st_size > 0, name
    assert not list(output.glob(".*tmp*"))  # atomic writes leave nothing behind
    performance = json.loads((output / "performance.json").read_text())
    main_entry = performance["experiments"]["main"]
    assert set(main_entry["modes"]) == {"independent", "comm", "full"}
    oracle = main_entry["baselines"]["oracle"]
    assert oracle["success_rate"] == 1.0 and oracle["epsilon"] == 0.0
    # The oracle at the agents' test ε: random moves make its paths longer, never shorter.
    assert oracle["eps"]["epsilon"] == 0.05
    assert oracle["eps"]["mean_steps_to_success"] > oracle["mean_steps_to_success"]
    full = main_entry["modes"]["full"]
    assert full["seeds"] == [641, 642] and full["best_seed"] in (641, 642)
    for condition in ("greedy", "eps"):
        rate = full[condition]["success_rate"]
        assert rate["n"] == 2 and rate["ci95"][0] <= rate["mean"] <= rate["ci95"][1]
        assert set(full[condition]["failures"]) == {"swapping", "parked", "looping", "other"}
    assert results["performance"] == performance


def test_the_episodes_shown_are_written_cell_by_cell(evaluated: tuple[dict, Path]) -> None:
    """trajectories.json holds the cells of the episodes trajectories.png draws: legal moves
    (one cell or none per step), a success ends with both agents on the target, and each
    agent's message at every step."""
    _, output = evaluated
    shown = json.loads((output / "trajectories.json").read_text("utf-8"))
    performance = json.loads((output / "performance.json").read_text("utf-8"))
    assert set(shown["modes"]) == {"independent", "comm", "full"}
    for mode, entry in shown["modes"].items():
        assert entry["seed"] == performance["experiments"]["main"]["modes"][mode]["best_seed"]
        assert entry["episodes"]
        for episode in entry["episodes"]:
            for cells in episode["cells"].values():
                steps = np.abs(np.diff(np.array(cells), axis=0)).sum(axis=1)
                assert len(cells) == episode["length"] + 1 and set(steps) <= {0, 1}
            ends = [cells[-1] for cells in episode["cells"].values()]
            assert (ends == [shown["target"]] * 2) == episode["success"]
            for sent in episode["messages"].values():  # one message per step, in [0, 1]
                assert len(sent) == episode["length"] and all(0 <= m <= 1 for m in sent)


def test_the_last_weights_are_tested_beside_the_selected_ones(
    evaluated: tuple[dict, Path], tiny_root: Path
) -> None:
    """train.py keeps each run's final weights in last_weights/ (listed with their sha256 in
    the manifest); evaluate.py tests them on the same episodes as the selected pair."""
    _, output = evaluated
    manifest = json.loads((tiny_root / "agent_models" / "manifest.json").read_text("utf-8"))
    listed = manifest["runs"]["full_seed641"]["last_weights"]["models"]
    assert listed == {a: f"last_weights/full_seed641_agent_{a}.pt" for a in "AB"}
    full = json.loads((output / "performance.json").read_text("utf-8"))["experiments"]["main"]
    full = full["modes"]["full"]
    for condition in ("greedy", "eps"):
        last = full["last_weights"][condition]
        assert last["episodes_per_seed"] == full[condition]["episodes_per_seed"] == EPISODES
        per_seed = [full["per_seed"][str(s)]["last_weights"][condition] for s in (641, 642)]
        assert last["success_rate"]["per_seed"] == [p["success_rate"] for p in per_seed]


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
            "on_target",
            "sees_target",
            "target_distance",
            "agent_distance",
            "time_step",
        }
    generalization = json.loads((output / "generalization.json").read_text())
    assert list(generalization["maps"]) == [str(k) for k in range(10)]
    assert all(entry["oracle"]["success_rate"] == 1.0 for entry in generalization["maps"].values())
    held_out = generalization["held_out"]
    # The 40 held-out maps (a fixed set), whatever the episodes per map.
    assert len(held_out["map_seeds"]) == 40 and set(held_out["success_rate"]) == set(POLICIES)
    assert held_out["success_rate"]["oracle"]["mean"] == 1.0
    assert set(held_out["modes"]) == {"independent", "comm", "full"}
    full = held_out["modes"]["full"]["eps"]
    assert full["over_maps"]["n"] == 40 and full["over_seeds"]["n"] == 2
    assert full["over_maps"]["mean"] == pytest.approx(full["over_seeds"]["mean"])
    beacon = np.array(full["over_maps"]["per_seed"]) - np.array(
        held_out["success_rate"]["beacon_explorer"]["per_seed"]
    )
    assert full["minus_beacon_explorer"]["per_seed"] == pytest.approx(beacon.tolist())


def test_mode_differences_are_written(evaluated: tuple[dict, Path]) -> None:
    _, output = evaluated
    performance = json.loads((output / "performance.json").read_text(encoding="utf-8"))
    main_entry = performance["experiments"]["main"]
    differences = main_entry["mode_differences"]
    assert set(differences) == {
        "comm_minus_independent",
        "full_minus_independent",
        "full_minus_comm",
    }
    for pair, conditions in differences.items():
        for condition, d in conditions.items():
            first, second = (
                main_entry["modes"][d[k]][condition]["success_rate"]["mean"]
                for k in ("first", "second")
            )
            assert pair == f"{d['first']}_minus_{d['second']}"
            assert d["mean"] == pytest.approx(first - second)
            assert d["established"] == (d["ci95"][0] > 0 or d["ci95"][1] < 0)
    rows = (output / "mode_differences.csv").read_text(encoding="utf-8").splitlines()
    assert rows[0].startswith("experiment,first,second,condition") and len(rows) == 1 + 6
    assert "Differences between modes" in (output / "comparison_table.md").read_text("utf-8")


def test_interventions_measures_and_decomposition_are_written(
    evaluated: tuple[dict, Path],
) -> None:
    _, output = evaluated
    interventions = json.loads((output / "interventions.json").read_text(encoding="utf-8"))
    modes = interventions["experiments"]["main"]
    assert set(modes) == {"comm", "full"} and set(modes["full"]) == {"message", "distance"}
    message = modes["full"]["message"]["eps"]
    assert set(message["delta_success"]) == set(INTERVENTIONS) - {"real"}
    assert message["verdict"] in ("content", "clock", "presence", "none")
    assert set(modes["full"]["distance"]["greedy"]["success"]) == {
        "real",
        "same_step",
        "random_step",
        "shuffled_time",
        "constant_mean",
    }
    measures = json.loads((output / "communication_measures.json").read_text(encoding="utf-8"))
    independent = measures["experiments"]["main"]["independent"]["aggregate"]
    for bins in ("K2", "K10"):
        assert set(independent[bins]) == set(MEASURES)
        assert independent[bins]["cic"]["A"]["mean"] == pytest.approx(0.0, abs=1e-12)  # masked
    performance = json.loads((output / "performance.json").read_text(encoding="utf-8"))
    decomposition = performance["experiments"]["main"]["modes"]["full"]["eps"][
        "failure_decomposition"
    ]
    assert set(decomposition) == {
        "navigation",
        "timing",
        "reached_and_left",
        "stay_on_target_share",
        "stay_share_more_staying",
        "stay_share_less_staying",
    }
    rows = (output / "interventions.csv").read_text(encoding="utf-8").splitlines()
    assert rows[0].startswith("experiment,mode,channel") and len(rows) > 20


def test_no_output_holds_an_absolute_path(
    evaluated: tuple[dict, Path], course_run: tuple[dict, Path], tiny_root: Path
) -> None:
    paths = [*evaluated[1].glob("*.*"), *course_run[1].glob("*.*")]
    for path in paths:
        if path.suffix in (".json", ".csv", ".md"):
            text = path.read_text(encoding="utf-8")
            assert str(tiny_root) not in text and str(PROBLEM2) not in text, path.name
            assert "NaN" not in text and "Infinity" not in text, path.name


def test_evaluator_matches_the_episode_loop_for_a_loaded_pair(tiny_root: Path) -> None:
    models = tiny_root / "agent_models"
    env = MultiAgentEnv(grid=load_map(models / "map.json"))
    pair = load_trained_models(models, "full", seed=641)
    results = MultiAgentEvaluator(env, *pair).run(300, epsilon=0.0)
    direct = run_episodes(
        VectorMultiAgentEnv(300, grid=env.grid), model_policy(*pair), 300, seed=EVAL_SEED
    )
    assert np.array_equal(results.successes, direct.successes)
    assert np.array_equal(results.lengths, direct.lengths)


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


def test_interventions_cannot_matter_to_independent_agents(tiny_root: Path) -> None:
    models = tiny_root / "agent_models"
    env = MultiAgentEnv(grid=load_map(models / "map.json"))
    evaluator = MultiAgentEvaluator(env, *load_trained_models(models, "independent"))
    tests = intervention_test(evaluator, 100)
    for channel in ("message", "distance"):
        for condition in ("greedy", "eps"):
            rates = tests[channel][condition]
            assert len(set(rates.values())) == 1, rates  # every intervention as the real input


def test_studies_are_discovered_with_their_labels(tiny_root: Path, tmp_path: Path) -> None:
    shutil.copytree(tiny_root / "agent_models", tmp_path / "agent_models")
    study = tmp_path / "studies" / "no_dial" / "agent_models"
    shutil.copytree(tiny_root / "agent_models", study)
    manifest = json.loads((study / "manifest.json").read_text())  # the batch's settings
    manifest["hyperparameters"]["comm_learning"] = "none"
    (study / "manifest.json").write_text(json.dumps(manifest))
    per_step = tmp_path / "studies" / "per_step" / "agent_models"  # no manifest: defaults
    per_step.mkdir(parents=True)
    for path in (tiny_root / "agent_models").glob("full_seed641_*"):
        shutil.copy(path, per_step)
    panel = tmp_path / "studies" / "panel" / "map3"  # the map panel evaluates itself
    shutil.copytree(tiny_root / "agent_models", panel / "agent_models")
    experiments = discover_experiments(tmp_path / "agent_models")
    assert [e.name for e in experiments] == ["main", "per_step", "no_dial"]
    assert experiments[2].label("comm") == "comm (message untrained (no DIAL))"
    assert experiments[1].seeds == {"full": [641]}
    assert np.array_equal(experiments[1].grid, experiments[0].grid)  # defaults: map seed 641


def _quick(models: Path, *extra: str) -> list[str]:
    """evaluate.py's flags for a quick run (the pipeline's: add ``PIPELINE_QUICK``)."""
    return ["--checkpoint", str(models), "--num_episodes", "10"] + [
        "--output_dir",
        str(models.parent / "out"),
        *extra,
    ]


PIPELINE_QUICK = ("--generalization_episodes", "5")
COMMANDS = {"evaluate.py": main, "analysis.pipeline": pipeline.main}  # each with its flags


def _run(command: str, models: Path) -> None:
    """``main`` of ``command`` on ``models``, quick."""
    extra = PIPELINE_QUICK if command == "analysis.pipeline" else ()
    COMMANDS[command](_quick(models, *extra))


def test_missing_or_corrupt_model_files_are_named(tiny_root: Path, tmp_path: Path) -> None:
    models = tmp_path / "agent_models"
    shutil.copytree(tiny_root / "agent_models", models)
    (models / "comm_seed642_agent_B.pt").unlink()
    for command in COMMANDS:
        with pytest.raises(SystemExit, match="comm_seed642_agent_B.pt"):
            _run(command, models)
    shutil.copy(tiny_root / "agent_models" / "comm_seed642_agent_B.pt", models)
    (models / "full_agent_A.pt").write_bytes(os.urandom(2000))  # the best pair damaged
    for command in COMMANDS:
        with pytest.raises(SystemExit, match="full_agent_A.pt"):
            _run(command, models)
    with pytest.raises(ValueError, match="full_agent_A.pt"):
        load_trained_models(models, "full")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_trained_models(tmp_path / "nowhere")
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_bad_checkpoint_paths_are_usage_errors(tiny_root: Path, tmp_path: Path, capsys) -> None:
    for path, message in (
        (tiny_root / "agent_models" / "full_agent_A.pt", "is a file"),
        (tmp_path / "nowhere", "no such folder"),
        (tmp_path, "no trained models"),
    ):
        for command in COMMANDS.values():
            with pytest.raises(SystemExit) as exit_info:
                command(["--checkpoint", str(path)])
            assert exit_info.value.code == 2
            assert message in capsys.readouterr().err


def test_checkpoint_is_relative_to_the_current_folder(
    tiny_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tiny_root.parent)
    args = parse_args(["--checkpoint", tiny_root.name])
    assert args.checkpoint.resolve() == (tiny_root / "agent_models").resolve()


def _export_bad(path: Path, kind: str) -> None:
    network = AgentDQN()
    with torch.no_grad():
        if kind == "nan":
            network.q_head.bias.fill_(float("nan"))
        else:
            network.message_head.bias.fill_(5.0)
    if kind == "nan":
        export_policy(network, "full", path)
        return

    class NoSigmoid(torch.nn.Module):  # returns the message logit itself
        def __init__(self) -> None:
            super().__init__()
            self.network = network

        def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            return self.network.forward_with_logit(obs)

    torch.jit.save(torch.jit.script(NoSigmoid()), str(path))


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch.jit.script of the bad model
@pytest.mark.parametrize(("kind", "message"), [("nan", "non-finite Q"), ("logit", "sigmoid")])
def test_models_with_bad_outputs_are_named(
    tiny_root: Path, tmp_path: Path, kind: str, message: str
) -> None:
    models = tmp_path / "agent_models"
    shutil.copytree(tiny_root / "agent_models", models)
    (models / "manifest.json").unlink()  # else the changed file is refused as "damaged"
    _export_bad(models / "comm_seed641_agent_B.pt", kind)
    for command in COMMANDS:
        with pytest.raises(SystemExit, match=f"comm_seed641_agent_B.pt.*{message}"):
            _run(command, models)
    assert not (tmp_path / "out").exists()  # refused before anything was written
    result = subprocess.run(
        [sys.executable, "evaluate.py", *_quick(models)],
        cwd=PROBLEM2,
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0 and "comm_seed641_agent_B.pt" in result.stderr


def _write_manifest(models: Path) -> dict:
    runs = {}
    for path in sorted(models.glob("*_seed*_agent_A.pt")):
        mode, seed = path.name.split("_seed")[0], int(path.name.split("_seed")[1].split("_")[0])
        name = f"{mode}_seed{seed}"
        files = {agent: f"{name}_agent_{agent}.pt" for agent in "AB"}
        runs[name] = {
            "mode": mode,
            "seed": seed,
            "models": files,
            "sha256": {a: sha256_of(models / f) for a, f in files.items()},
            "selection": {"greedy": 0.0, "eps": 0.0, "score": 0.0},
        }
    best = {}
    for mode in ("independent", "comm", "full"):
        content = (models / f"{mode}_agent_A.pt").read_bytes()
        best[mode] = next(
            n
            for n, r in runs.items()
            if r["mode"] == mode and (models / r["models"]["A"]).read_bytes() == content
        )
    manifest = {
        "format": 1,
        "modes": ["independent", "comm", "full"],
        "seeds": [641, 642],
        "map_seed": 641,
        "reward_mode": "arrival",
        "hyperparameters": {"max_steps": 50, "grid_size": 10, "map_seed": 641},
        "code_version": "0" * 64,
        "runs": runs,
        "best": best,
    }
    (models / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return manifest


def test_manifest_runs_are_evaluated_and_foreign_or_changed_files_refused(
    tiny_root: Path, tmp_path: Path
) -> None:
    models = tmp_path / "agent_models"
    shutil.copytree(tiny_root / "agent_models", models)
    manifest = _write_manifest(models)
    (experiment,) = discover_experiments(models)
    assert experiment.manifest == manifest and experiment.seeds["full"] == [641, 642]
    del manifest["runs"]["full_seed642"]  # a manifest listing one full seed only
    manifest["runs"]["full_seed641"]["sha256"]["A"] = sha256_of(models / "full_seed641_agent_A.pt")
    manifest["best"]["full"] = "full_seed641"
    (models / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    with pytest.raises(ValueError, match="not listed in manifest.json.*full_seed642_agent_A.pt"):
        discover_experiments(models)
    for agent in "AB":
        (models / f"full_seed642_agent_{agent}.pt").unlink()
        shutil.copy(models / f"full_seed641_agent_{agent}.pt", models / f"full_agent_{agent}.pt")
    (experiment,) = discover_experiments(models)
    assert experiment.seeds["full"] == [641] and best_seed(experiment, "full") == 641
    shutil.copy(models / "comm_seed641_agent_A.pt", models / "comm_seed642_agent_A.pt")
    with pytest.raises(ValueError, match="comm_seed642_agent_A.pt: damaged or replaced"):
        discover_experiments(models)


def test_cli_survives_a_cp1252_console_and_without_manifest_notes_the_files_found(
    tiny_root: Path, tmp_path: Path
) -> None:
    """A whole evaluation in its own process, on a cp1252 console, of model files without
    their manifest (e.g. trained before manifests existed). Only the full mode's files are
    copied: a third of the work (one mode, one GIF); every mode's outputs are tested on the
    ``evaluated`` fixture's run."""
    models = tmp_path / "agent_models"
    models.mkdir()
    for path in (tiny_root / "agent_models").glob("*.*"):
        if path.name.startswith("full_") or path.name in ("map.json", "hyperparameters.json"):
            shutil.copy(path, models)
    result = subprocess.run(
        [sys.executable, "evaluate.py", *_quick(models, "--render")],
        cwd=PROBLEM2,
        capture_output=True,
        env=os.environ | {"PYTHONIOENCODING": "cp1252"},
    )
    assert result.returncode == 0, result.stderr.decode("cp1252", "replace")
    assert b"success greedy" in result.stdout
    assert b"no manifest.json" in result.stdout
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "analysis.baselines",
            "--episodes",
            "20",
            "--map_seeds",
            "0",
            "--output",
            str(tmp_path / "b.json"),
        ],
        cwd=PROBLEM2,
        capture_output=True,
        env=os.environ | {"PYTHONIOENCODING": "cp1252"},
    )
    assert result.returncode == 0


def test_course_interface_as_a_grader_uses_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    model_A, model_B = load_trained_models()  # the committed best full pair, from any folder
    env = MultiAgentEnv(seed=641)
    for pair in ((model_A, model_B), (AgentDQN(), DuelingDQN())):  # TorchScript and plain
        evaluator = MultiAgentEvaluator(env, *pair)
        performance = evaluator.evaluate_performance(num_episodes=50)
        assert 0.0 <= performance["success_rate"] <= 1.0
    assert evaluator.visualize_trajectory(num_episodes=20) == Path("results/trajectory.png")
    assert evaluator.plot_communication_heatmap(num_episodes=20) == Path("results/comm_heatmap.png")
    assert (tmp_path / "results" / "trajectory.png").stat().st_size > 0
    assert (tmp_path / "results" / "comm_heatmap.png").stat().st_size > 0
    report = {"success": performance["success_rate"], "modes": ["full"], "nested": {"a": [1, 2]}}
    create_evaluation_report(report)
    written = tmp_path / "results" / "evaluation_report.json"
    assert json.loads(written.read_text(encoding="utf-8")) == report
    broken = AgentDQN()
    with torch.no_grad():
        broken.hidden.weight.fill_(float("nan"))
    with pytest.raises(ValueError, match="model_B.*non-finite"):
        MultiAgentEvaluator(env, AgentDQN(), broken)


def test_help_states_defaults_and_the_path_rule(capsys) -> None:
    for module in (evaluate_module, pipeline, baselines):
        with pytest.raises(SystemExit) as exit_info:
            module.main(["--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        assert "default:" in text and "current folder" in text


def test_baselines_take_both_list_forms(tmp_path: Path) -> None:
    for form in (["0,1"], ["0", "1"]):
        output = tmp_path / f"{len(form)}.json"
        baselines.main(["--episodes", "20", "--map_seeds", *form, "--output", str(output)])
        assert list(json.loads(output.read_text(encoding="utf-8"))["maps"]) == ["0", "1"]
    with pytest.raises(SystemExit):
        baselines.main(["--map_seeds", "0,x"])


def test_models_on_maps_batches_every_pair_as_if_run_alone(tiny_root: Path) -> None:
    """Many model pairs in one batch (one policy a block) give each pair's own results."""
    experiment = discover_experiments(tiny_root / "agent_models")[0]
    maps = (1000, 1001)
    batched = models_on_maps(experiment, 0.05, maps, 30)
    for mode, seeds in experiment.seeds.items():
        for k, seed in enumerate(seeds):
            alone = experiment_evaluator(experiment, 0.05, mode, seed).test_generalization(
                num_episodes=30, oracle=False, map_seeds=maps
            )
            assert alone["map_seeds"] == list(maps)
            for condition in ("greedy", "eps"):
                rates = [alone["maps"][str(m)][condition] for m in maps]
                assert batched[mode][condition][k].tolist() == rates
