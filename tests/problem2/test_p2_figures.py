"""The figures: each committed one is what its redraw command makes from the committed
results (no training), the redraw commands refuse what they cannot draw from, and the
choices that make a figure readable (scales, names, empty slots) hold."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from analysis import training_curves
from analysis.baselines import POLICIES, POLICY_LABELS
from analysis.estimate_plots import plot_measures
from analysis.plots import message_range
from matplotlib.figure import Figure
from studies import map_pool_study, reward_study
from studies.memory import study as memory_study
from train import RETURN_NAMES
from vector_env import REWARD_MODES

from tests.conftest import PROBLEM2

RESULTS = PROBLEM2 / "results"
STUDIES = RESULTS / "studies"


def copy_batch(source: Path, destination: Path) -> Path:
    """The parts of a trained batch that its training curves are drawn from."""
    (destination / "agent_models").mkdir(parents=True)
    for name in ("manifest.json", "hyperparameters.json"):
        shutil.copy(source / "agent_models" / name, destination / "agent_models" / name)
    shutil.copytree(source / "training_logs", destination / "training_logs")
    (destination / "training_logs" / "training_curves.png").unlink()
    return destination


@pytest.mark.parametrize(
    "batch", [RESULTS, STUDIES / "reward" / "per_step"], ids=["main", "reward"]
)
def test_committed_training_curves_are_redrawn_byte_for_byte(batch: Path, tmp_path: Path) -> None:
    copy = copy_batch(batch, tmp_path / "batch")
    assert training_curves.main([str(copy)]) == [copy / "training_logs" / "training_curves.png"]
    drawn = (copy / "training_logs" / "training_curves.png").read_bytes()
    assert drawn == (batch / "training_logs" / "training_curves.png").read_bytes()


def test_curve_redraw_refuses_a_folder_without_a_batch_or_with_a_log_missing(
    tmp_path: Path, capsys
) -> None:
    good = copy_batch(RESULTS, tmp_path / "good")
    broken = copy_batch(RESULTS, tmp_path / "broken")
    (broken / "training_logs" / "comm_seed642.csv").unlink()
    refused = {tmp_path / "none": "no agent_models/manifest.json", broken: "lacks comm_seed642.csv"}
    for folder, message in refused.items():
        with pytest.raises(SystemExit) as exit_info:
            training_curves.main([str(good), str(folder)])  # every folder checked first
        assert exit_info.value.code == 2 and message in capsys.readouterr().err
    assert not (good / "training_logs" / "training_curves.png").exists()


def test_every_reward_the_curves_can_sum_is_named() -> None:
    assert set(RETURN_NAMES) == set(REWARD_MODES)


@pytest.mark.parametrize(
    "study, json_name, png_name",
    [
        (map_pool_study, "map_pool/map_pool.json", "map_pool/map_pool.png"),
        (memory_study, "memory/memory.json", "memory/memory.png"),
        (reward_study, "reward/reward_study.json", "reward/reward_study.png"),
    ],
    ids=["map_pool", "memory", "reward"],
)
def test_plot_only_redraws_the_committed_study_figure(
    study, json_name: str, png_name: str, tmp_path: Path
) -> None:
    shutil.copy(STUDIES / json_name, tmp_path / Path(json_name).name)
    study.main(["--plot_only", "--output_dir", str(tmp_path)])
    drawn = (tmp_path / Path(png_name).name).read_bytes()
    assert drawn == (STUDIES / png_name).read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [Path(json_name).name, Path(png_name).name]
    )


@pytest.mark.parametrize("study", [map_pool_study, memory_study, reward_study])
def test_plot_only_without_the_study_json_is_a_usage_error(study, tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        study.main(["--plot_only", "--output_dir", str(tmp_path)])
    assert exit_info.value.code == 2 and "--plot_only:" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_every_baseline_has_one_display_name() -> None:
    assert set(POLICY_LABELS) == set(POLICIES)
    assert POLICY_LABELS["sweep_explorer"] == "sweeping explorer"


def test_a_row_of_message_maps_is_coloured_over_its_own_range() -> None:
    means = np.full((2, 3, 3), np.nan)
    means[0, 0, :2] = [0.2, 0.5]
    means[1, 2, 2] = 0.4
    assert message_range(means) == (0.2, 0.5)
    low, high = message_range(np.full((2, 3, 3), 0.998))  # a constant message
    assert high - low == pytest.approx(0.001) and (low + high) / 2 == pytest.approx(0.998)


def test_cic_of_a_mode_without_a_receiver_is_said_not_drawn(tmp_path: Path) -> None:
    measures = json.loads(
        (RESULTS / "evaluation_results" / "communication_measures.json").read_text("utf-8")
    )["experiments"]["main"]
    aggregates = {mode: entry["aggregate"] for mode, entry in measures.items()}
    captured = {}
    save = Figure.savefig

    def record(self: Figure, *args, **kwargs) -> None:
        captured["figure"] = self
        save(self, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Figure, "savefig", record)
        plot_measures(aggregates, "K2", tmp_path / "measures.png")
    cic_axes = next(a for a in captured["figure"].axes if "CIC" in a.get_title())
    texts = [t.get_text() for t in cic_axes.texts]
    assert sum("by construction" in t for t in texts) == 1  # independent only
    assert sum(t.strip().replace(".", "").isdigit() for t in texts) == 4  # comm, full x A, B
    shared = {a.get_xlim() for a in captured["figure"].axes}
    assert len(shared) == 1  # every panel on one scale
