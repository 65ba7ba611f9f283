"""The listener at two million steps (studies/one_step/beacon_long.py): the screen's R + H + D
cell and its independent twin R + H, longer, on eight training seeds, with the pass rule that
decides whether the held-out study runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from studies.one_step import beacon_long, beacon_screen

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")


def runs_with(full: list[float], independent: list[float]) -> list[dict]:
    """Records as ``train_cell`` returns them, one per seed of ``beacon_long.SEEDS``."""
    runs = []
    for cell, mode, scores in (
        (beacon_long.FULL, "full", full),
        (beacon_long.INDEPENDENT, "independent", independent),
    ):
        for seed, score in zip(beacon_long.SEEDS, scores, strict=True):
            rates = {"eps": score, "greedy": score}
            runs.append({"cell": cell, "mode": mode, "seed": seed, "best": rates})
            runs[-1] |= {"best_env_steps": 1, "seconds": 1.0}
    return runs


def test_the_cells_are_the_screens_rhd_and_its_independent_twin_at_two_million_steps() -> None:
    screen = beacon_screen.screen_cells()
    assert beacon_screen.independent_twin("RHD", screen) == "RH"
    cells = beacon_long.long_cells()
    longer = {"total_steps": 2_000_000}
    full, independent = cells[beacon_long.FULL], cells[beacon_long.INDEPENDENT]
    assert full["changes"] == screen["RHD"]["changes"] | longer and full["modes"] == ["full"]
    assert independent["changes"] == screen["RH"]["changes"] | longer
    assert independent["modes"] == ["independent"]
    seeds = beacon_long.SEEDS
    assert seeds == tuple(range(100, 108))


@pytest.mark.parametrize(
    "full, passed",
    [
        ([0.58, 0.58, 0.58, 0.58, 0.58, 0.58, 0.58, 0.58], True),  # +8 points on every seed
        ([0.579, 0.58, 0.58, 0.58, 0.58, 0.58, 0.58, 0.58], False),  # mean just below +8
        ([0.9, 0.9, 0.9, 0.9, 0.2, 0.2, 0.2, 0.2], False),  # +5 points on average
        ([0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.1], True),  # one seed below: interval above 0
        ([0.9, 0.9, 0.9, 0.9, 0.9, 0.1, 0.1, 0.1], False),  # +10 points, interval reaches 0
    ],
)
def test_the_pass_rule_needs_eight_points_and_an_interval_above_zero(
    full: list[float], passed: bool
) -> None:
    summary = beacon_long.summarise(runs_with(full, [0.5] * 8), beacon_long.long_cells(), 10)
    rule = summary["pass_rule"]
    assert rule["passed"] is passed and rule["rule"] == beacon_long.RULE
    difference = summary["cells"][beacon_long.FULL]["full_minus_independent_eps"]
    assert difference["per_seed"] == pytest.approx([f - 0.5 for f in full])
    assert summary["cells"][beacon_long.FULL]["independent_from"] == beacon_long.INDEPENDENT


def test_a_smoke_run_writes_the_table_and_keeps_wall_times_apart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(beacon_long, "SEEDS", (100, 101))  # the real run has eight
    written = []
    for name in ("first", "second"):
        out = tmp_path / name
        beacon_long.main(["--total_steps", "6000", "--output_dir", str(out), "--workers", "1"])
        written.append((out / "beacon_long.json").read_bytes())
    assert written[0] == written[1]  # the same runs give the same bytes
    results = json.loads(written[0])
    assert "seconds" not in written[0].decode() and results["total_steps"] == 6000
    assert results["training_seeds"] == [100, 101]
    assert isinstance(results["pass_rule"]["passed"], bool)
    timing = json.loads((out / "timing.json").read_text())
    assert len(timing) == 4 and all(seconds > 0 for seconds in timing.values())
    logs = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.csv"))
    assert logs == [
        "RHD_2M/training_logs/full_seed100.csv",
        "RHD_2M/training_logs/full_seed101.csv",
        "RH_2M/training_logs/independent_seed100.csv",
        "RH_2M/training_logs/independent_seed101.csv",
    ]
    assert "pass rule:" in capsys.readouterr().out


def test_smoke_runs_into_the_results_and_budgets_without_an_update_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        beacon_long.parse_args(["--total_steps", "100"])
    with pytest.raises(SystemExit):
        beacon_long.parse_args(["--total_steps", "3000", "--output_dir", str(tmp_path / "out")])
    assert "--total_steps: must be at least learning_starts" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
