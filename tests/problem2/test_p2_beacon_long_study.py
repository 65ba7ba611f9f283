"""The held-out study of the listener at two million steps (studies/one_step/beacon_long_study.py):
its runs, its comparisons with the best independent agents of any training, the verdicts
fixed before the test, the summary rebuilt from the recorded runs, and a smoke run (one real
run; the others stand-ins) that writes the study whole."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
from studies.one_step import beacon_long, beacon_long_study, beacon_study, unseen

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")
TESTED = beacon_study.STUDY_DIR / "beacon.json"


def test_full_and_independent_on_ten_seeds_come_first_all_with_the_confirmed_cell(
    tmp_path: Path,
) -> None:
    jobs = beacon_long_study.jobs_of(tmp_path, {}, 500)
    assert len(jobs) == 35
    first = [(label, seed) for label, _, seed, *_ in jobs[:20]]
    assert first == [(m, s) for s in range(10) for m in ("full", "independent")]
    later = [(label, mode, seed) for label, mode, seed, *_ in jobs[20:]]
    assert later == [(m, m, s) for m in ("comm", "distance") for s in range(5)] + [
        (beacon_long_study.RECIPE_2M, "independent", s) for s in range(5)
    ]
    confirmed = beacon_long.long_cells()[beacon_long.FULL]["changes"]
    assert all(job[3] == confirmed for job in jobs[:30])
    assert all(job[3] == {"total_steps": 2_000_000} for job in jobs[30:])  # the recipe, longer
    assert all(job[6] == 500 for job in jobs)


def test_the_screens_best_independent_cell_is_read_as_beacon_study_tested_it() -> None:
    screen = unseen.read_json(beacon_long_study.AROUND_DIR / "beacon_around.json")
    tested = unseen.read_json(TESTED)
    cell, success = beacon_long_study.screen_best_independent(screen, tested)
    assert cell == screen["best_independent"] == tested["best_independent"]["cell"]
    assert sorted(success) == [0, 1, 2, 3, 4]
    per_seed = tested["best_independent"]["success"]["eps"]["per_seed"]
    assert [success[s]["eps"] for s in range(5)] == per_seed
    with pytest.raises(SystemExit):
        beacon_long_study.screen_best_independent(
            screen, tested | {"best_independent": {"cell": "R"}}
        )


def stats(per_seed: list[float], low: float, high: float) -> dict[str, Any]:
    return {"mean": sum(per_seed) / len(per_seed), "ci95": [low, high], "per_seed": per_seed}


def results_with(full: list[float], difference: dict, best_low: float, replaced: float) -> dict:
    """The parts of a summary the verdicts read."""
    interventions = {
        f"{channel}.same_step": {"eps": stats([replaced], replaced - 0.01, replaced + 0.01)}
        for channel in ("message", "distance")
    }
    full_stats = {"eps": stats(full, 0, 1), "interventions_delta_success": interventions}
    return {
        "held_out": {
            "modes": {"full": full_stats},
            "differences": {"full-independent": {"eps": difference}},
        },
        "best_independent": {"x": {"full_minus": {"eps": stats([0.1], best_low, 0.2)}}},
    }


@pytest.mark.parametrize(
    "full, difference, best_low, replaced, holding",
    [
        (
            [0.5] * 10,
            stats([0.1] * 10, 0.1, 0.1),
            0.01,
            -0.05,
            set(beacon_long_study.VERDICTS) - {"every_seed_at_least_0.68"},
        ),
        ([0.499] * 10, stats([0.099] * 10, 0.0, 0.2), 0.0, -0.005, set()),
        (
            [0.7] * 10,
            stats([0.3] * 10, -0.01, 0.5),
            -0.1,
            0.02,
            {"full_at_least_0.50", "every_seed_at_least_0.68"},
        ),
    ],
)
def test_the_verdicts_apply_the_rules_fixed_before_the_test(
    full: list[float], difference: dict, best_low: float, replaced: float, holding: set
) -> None:
    verdicts = beacon_long_study.verdicts(results_with(full, difference, best_low, replaced))
    assert set(verdicts) == set(beacon_long_study.VERDICTS)
    assert {name for name, v in verdicts.items() if v["holds"]} == holding


def test_a_smoke_run_writes_the_study_whole_without_wall_times(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every run trains for real (6000 steps); its held-out test is replaced by a recorded
    run of beacon_study's (the 40 maps' tests take minutes), so the summary, the figure and
    the drawn episode (the trained full pair, 1 episode per map) are exercised."""
    monkeypatch.setattr(beacon_long_study, "PAIRED_SEEDS", (0,))
    monkeypatch.setattr(beacon_long_study, "OTHER_SEEDS", (0,))
    recorded = json.loads(TESTED.read_text())["runs"]

    def recorded_test(trainer: Any, label: str, *rest: Any) -> dict[str, Any]:
        record = copy.deepcopy(recorded[f"{trainer.mode}_seed{trainer.seed}"])
        return record | {"mode": label, "seconds": {"training": 1.0, "total": 1.0}}

    monkeypatch.setattr(unseen, "held_out_record", recorded_test)
    out = tmp_path / "out"
    argv = ["--total_steps", "6000", "--episodes_per_map", "1", "--output_dir", str(out)]
    results = beacon_long_study.main([*argv, "--workers", "1"])
    written = (out / "beacon_long_study.json").read_text()
    assert "seconds" not in written and json.loads(written)["verdicts"] == results["verdicts"]
    assert (out / "beacon_long_study.png").stat().st_size > 0
    assert sorted(json.loads((out / "timing.json").read_text())) == sorted(
        [
            "full_seed0",
            "independent_seed0",
            "comm_seed0",
            "distance_seed0",
            "recipe_independent_2M_seed0",
        ]
    )
    models = {p.name for p in (out / "agent_models").glob("*.pt")}
    assert {f"{beacon_long_study.RECIPE_2M}_seed0_agent_{a}.pt" for a in "AB"} <= models
    assert len(models) == 10
    assert set(results["best_independent"]) == {"screen HD 2M", "recipe 1M", "recipe 2M"}
    assert results["best_independent"]["recipe 2M"]["seeds"] == [0]
    assert isinstance(results["drawn_episode"]["in_words"], str)
    assert "full_minus_independent:" in capsys.readouterr().out


def test_it_needs_the_passed_confirmation_and_refuses_smoke_runs_into_the_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        beacon_long_study.parse_args(["--total_steps", "6000"])
    with pytest.raises(SystemExit):
        beacon_long_study.parse_args(["--total_steps", "3000", "--output_dir", str(tmp_path / "a")])
    assert "--total_steps: must be at least learning_starts" in capsys.readouterr().err
    confirmation = json.loads((beacon_long.LONG_DIR / "beacon_long.json").read_text())
    failed = tmp_path / "failed.json"
    failed.write_text(json.dumps(confirmation | {"pass_rule": {"passed": False}}))
    argv = ["--total_steps", "6000", "--output_dir", str(tmp_path / "b"), "--workers", "1"]
    with pytest.raises(SystemExit, match="did not pass"):
        beacon_long_study.main([*argv, "--confirmation", str(failed)])
    assert not (tmp_path / "b").exists()


def test_the_summary_rebuilt_from_the_recorded_runs_is_the_committed_json(tmp_path: Path) -> None:
    """--summary_only trains nothing: from the runs alone (every other key dropped) and seed
    0's saved full pair it writes the committed JSON byte for byte."""
    committed = beacon_long_study.STUDY_DIR
    folder = tmp_path / "held_out"
    (folder / "agent_models").mkdir(parents=True)
    for model in (committed / "agent_models").glob("full_seed0_agent_*.pt"):
        (folder / "agent_models" / model.name).write_bytes(model.read_bytes())
    name = "beacon_long_study.json"
    recorded = json.loads((committed / name).read_text(encoding="utf-8"))
    runs_only = {key: recorded[key] for key in ("runs", "recipe_2M_runs")}
    (folder / name).write_text(json.dumps(runs_only), encoding="utf-8")
    beacon_long_study.main(["--summary_only", "--output_dir", str(folder)])
    assert (folder / name).read_bytes() == (committed / name).read_bytes()
