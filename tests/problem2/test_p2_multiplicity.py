"""Holm's correction and the bootstrap p-values the report's "established" rests on."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from studies import multiplicity

RESULTS = Path(__file__).resolve().parents[2] / "problem2" / "results"


def test_holm_multiplies_the_sorted_p_values_and_keeps_their_order() -> None:
    # sorted: 0.01 * 4, 0.02 * 3, 0.03 * 2 -> 0.06 (monotone), 0.5 * 1
    adjusted = multiplicity.holm([0.03, 0.01, 0.5, 0.02])
    assert adjusted == pytest.approx([0.06, 0.04, 0.5, 0.06])


def test_holm_caps_at_one_and_rejects_fewer_than_the_uncorrected_test() -> None:
    p = [0.001, 0.012, 0.04, 0.9]
    adjusted = multiplicity.holm(p)
    assert adjusted == pytest.approx([0.004, 0.036, 0.08, 0.9])
    assert multiplicity.holm([0.6, 0.7]) == [1.0, 1.0]
    assert sum(x <= 0.05 for x in adjusted) == 2 < sum(x <= 0.05 for x in p)


def test_a_contrast_no_resample_brings_to_zero_gets_the_smallest_p() -> None:
    groups = {"a": [0.9, 0.95, 1.0], "b": [0.1, 0.2, 0.15]}
    p = multiplicity.bootstrap_p_value(groups, {"a": 1.0, "b": -1.0}, n_resamples=999)
    assert p == pytest.approx(2 / 1000)


def test_equal_groups_give_p_one_and_overlapping_ones_a_middle_p() -> None:
    same = {"a": [0.5, 0.5], "b": [0.5, 0.5]}
    assert multiplicity.bootstrap_p_value(same, {"a": 1.0, "b": -1.0}, n_resamples=500) == 1.0
    mixed = {"d": [-0.02, 0.01, 0.03, -0.01, 0.02]}
    assert 0.2 < multiplicity.bootstrap_p_value(mixed, {"d": 1.0}, n_resamples=4000) < 1.0


def test_the_corrected_verdict_uses_only_rejected_losses() -> None:
    tests = {
        "same_step": {"mean": -0.2, "rejected": False},
        "random_step": {"mean": -0.1, "rejected": True},
        "constant_0": {"mean": -0.3, "rejected": True},
    }
    assert multiplicity.corrected_verdict(tests) == "clock"
    tests["random_step"]["rejected"] = False
    assert multiplicity.corrected_verdict(tests) == "presence"
    tests["constant_0"]["mean"] = 0.3  # a rejected gain is no loss
    assert multiplicity.corrected_verdict(tests) == "none"


def test_the_committed_file_is_what_the_script_computes_from_the_committed_results() -> None:
    panel = json.loads((RESULTS / "studies" / "panel" / "panel.json").read_text("utf-8"))
    probes = json.loads((RESULTS / "evaluation_results" / "interventions.json").read_text("utf-8"))
    memory_panel = json.loads(multiplicity.MEMORY_PANEL.read_text("utf-8"))
    committed = json.loads(multiplicity.OUTPUT.read_text("utf-8"))
    computed = multiplicity.multiplicity(panel, probes, memory_panel)
    assert json.loads(json.dumps(computed)) == committed
    effects = committed["panel_effects"]["summary"]
    assert effects["tests"] == 4 * len(panel["maps"])
    assert effects["rejected"] <= effects["rejected_uncorrected"]


def _memory_map(rates: dict[str, list[float]]) -> dict:
    coefficients = {
        "message": {"comm": 1.0, "independent": -1.0},
        "distance": {"distance": 1.0, "independent": -1.0},
    }
    return {
        "conditions": {
            "eps": {
                "success": {
                    m: {"memory": {"per_seed": r}, "memoryless": {}} for m, r in rates.items()
                },
                "channel_effects_with_memory": {
                    e: {
                        "coefficients": c,
                        "mean": sum(sum(rates[g]) / len(rates[g]) * w for g, w in c.items()),
                        "established": False,
                    }
                    for e, c in coefficients.items()
                },
            }
        }
    }


def test_the_memory_panel_is_a_family_of_its_own_tested_on_the_memory_agents_rates() -> None:
    clear = {
        "independent": [0.1, 0.12, 0.11],
        "comm": [0.9, 0.92, 0.91],
        "distance": [0.1, 0.12, 0.11],
    }
    noise = {"independent": [0.5, 0.6, 0.4], "comm": [0.55, 0.45, 0.6], "distance": [0.5, 0.6, 0.4]}
    family = multiplicity.memory_panel_effects(
        {"maps": {"1": _memory_map(clear), "2": _memory_map(noise)}}
    )
    assert family["summary"]["tests"] == 4
    assert family["maps"]["1"]["message"]["verdict"] == "gain"
    assert family["maps"]["1"]["distance"]["verdict"] == "unclear"  # identical rates: p = 1
    assert family["maps"]["2"]["message"]["verdict"] == "unclear"
    # the family leaves the other two untouched and is absent without its results
    panel = json.loads((RESULTS / "studies" / "panel" / "panel.json").read_text("utf-8"))
    probes = json.loads((RESULTS / "evaluation_results" / "interventions.json").read_text("utf-8"))
    without = multiplicity.multiplicity(panel, probes)
    assert "memory_panel_effects" not in without
    committed = json.loads(multiplicity.OUTPUT.read_text("utf-8"))
    assert committed["memory_panel_effects"]["summary"]["tests"] == 48
    assert json.loads(json.dumps(without["panel_effects"])) == committed["panel_effects"]
