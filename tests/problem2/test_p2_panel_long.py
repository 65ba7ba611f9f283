"""The longer-run check beside the map panel: which map it picks and what it reads."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from studies.panel_long import hardest_map, main, validation_at


def panel_with(full_success: dict[int, float]) -> dict:
    """A panel.json-shaped dict with full's mean success at ε on each map."""
    maps = {
        str(m): {"success": {"full": {"eps": {"mean": value}}}} for m, value in full_success.items()
    }
    return {"protocol": {"map_seeds": list(full_success)}, "maps": maps}


def test_the_hardest_map_is_where_full_succeeds_least_first_in_panel_order_on_a_tie() -> None:
    assert hardest_map(panel_with({641: 1.0, 0: 0.4, 1: 0.7})) == 0
    assert hardest_map(panel_with({641: 0.9, 3: 0.5, 2: 0.5})) == 3


def test_validation_is_read_at_the_last_evaluation_within_the_budget(tmp_path: Path) -> None:
    for seed, values in ((1, (0.1, 0.5, 0.9)), (2, (0.2, 0.4, 0.6))):
        with open(tmp_path / f"full_seed{seed}.csv", "w", newline="", encoding="utf-8") as f:
            writer = csv.writer(f)
            writer.writerow(["env_steps", "eval_success_eps"])
            writer.writerows(zip((0, 100, 200), values, strict=True))
    assert validation_at(tmp_path, [1, 2], 150)["per_seed"] == [0.5, 0.4]
    assert validation_at(tmp_path, [1, 2], 200)["mean"] == pytest.approx(0.75)


def test_a_folder_without_panel_json_is_refused_before_any_work(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--panel_dir", str(tmp_path)])
    assert exit_info.value.code == 2
    assert not any(tmp_path.iterdir())
