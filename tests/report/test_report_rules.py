"""Every branch of the interpretation rules: the wording must follow the numbers."""

from __future__ import annotations

import pytest
from report_rules import (
    dial_sentence,
    drift_discussion,
    generalisation_sentence,
    hazard_value_loss,
    interval_relation,
    join_words,
    message_effect,
    ordering_sentence,
    parking_sentence,
    pct,
    pct_ci,
    sweep_comparison,
    sweep_cost,
    target_check,
    verification_sentence,
)


def test_formatting() -> None:
    assert pct(0.734) == "73.4 %" and pct(None) == "–" and pct(float("nan")) == "–"
    assert pct_ci(0.5, [0.4, 0.6]) == "50.0 % [40.0, 60.0]" and pct_ci(0.5, None) == "50.0 %"
    assert join_words(["a"]) == "a" and join_words(["a", "b", "c"]) == "a, b and c"


def test_sweeps_equal_or_not() -> None:
    assert "the same number of sweeps (31)" in sweep_comparison(31, 31)
    assert "QI needs 1 more sweep" in sweep_comparison(31, 32)
    assert "VI needs 2 more sweep" in sweep_comparison(33, 31)


def test_sweep_cost_agrees_or_not() -> None:
    assert "agree within a factor 1.5" in sweep_cost(5e-5, 6e-5)
    assert "QI was 3.0× slower" in sweep_cost(1e-5, 3e-5)
    assert "VI was 2.0× slower" in sweep_cost(4e-5, 2e-5)


def _verification(within: bool, contains: bool) -> dict:
    return {"policy_evaluation_max_error": 1e-4, "residual_bound": 6e-4, "within_bound": within,
            "monte_carlo": {"episodes": 100, "mean_return": 4.9, "ci99": [4.8, 5.0],
                            "contains_v_start": contains}}  # fmt: skip


def test_verification_pass_and_fail() -> None:
    passed = verification_sentence(_verification(True, True))
    assert "inside the Bellman-residual bound" in passed and "contains V(start)" in passed
    failed = verification_sentence(_verification(False, False))
    assert "fails this check" in failed and "does NOT contain" in failed


def _setting(drift: float, v: float, detours: list[int], penalties: float = 0.1) -> dict:
    return {"drift": drift, "v_start": v, "expected_steps": 8 + 10 * drift,
            "expected_penalty_visits": penalties, "detour_states": detours}  # fmt: skip


def test_drift_without_detours() -> None:
    text = " ".join(drift_discussion([_setting(0.0, 6.0, []), _setting(0.1, 5.0, [])]))
    assert "falls monotonically" in text and "does the optimal policy deviate" in text


def test_drift_with_detours_and_non_monotone_values() -> None:
    settings = [_setting(0.0, 6.0, []), _setting(0.2, 6.5, [20]), _setting(0.3, 1.0, [0, 6], 0.0)]
    text = " ".join(drift_discussion(settings))
    assert "non-monotonically" in text
    assert "Up to drift 0 the policy stays on a shortest path; from drift 0.2" in text
    assert "(4, 0)" in text and "At drift 0.3, 2 states deviate" in text


def test_drift_detours_from_the_first_level() -> None:
    text = " ".join(drift_discussion([_setting(0.1, 5.0, [3])]))
    assert "Already at drift 0.1" in text


def test_hazard_value_loss() -> None:
    clean, noisy = [5.0] * 25, [5.0] * 25
    noisy[15] = 1.0  # (3, 0): a penalty cell
    worst, near = hazard_value_loss(clean, noisy, hazards=[15], top=1)
    assert worst == [15] and near
    noisy = [5.0] * 25
    noisy[4] = 1.0  # (0, 4): far from (3, 0)
    worst, near = hazard_value_loss(clean, noisy, hazards=[15], top=1)
    assert worst == [4] and not near


def test_interval_relation() -> None:
    assert interval_relation([0.5, 0.6], [0.1, 0.4]) == "above"
    assert interval_relation([0.1, 0.4], [0.5, 0.6]) == "below"
    assert interval_relation([0.1, 0.5], [0.4, 0.6]) == "overlap"
    assert interval_relation(None, [0.4, 0.6]) == "overlap"


@pytest.mark.parametrize(
    ("difference", "ci", "verdict"),
    [(0.1, (0.05, 0.15), "helps"), (-0.1, (-0.15, -0.05), "hurts"), (0.02, (-0.01, 0.05), "none")],
)
def test_message_effect_only_claims_a_difference_outside_its_ci(difference, ci, verdict) -> None:
    found, sentence = message_effect(difference, ci)
    assert found == verdict
    assert ("no evidence" in sentence) == (verdict == "none")


def test_target_check() -> None:
    assert "meets" in target_check("full", 0.9, 0.85)
    assert "MISSES the target of 85 % by 5.0 points" in target_check("full", 0.8, 0.85)
    assert "no result" in target_check("full", None, 0.85)


def test_ordering_sentence_branches() -> None:
    means = {"full": 0.8, "comm": 0.5, "independent": 0.3}
    separated = {"full": [0.75, 0.85], "comm": [0.45, 0.55], "independent": [0.25, 0.35]}
    text = ordering_sentence(means, separated)
    assert "as expected" in text and "separate full vs comm and comm vs independent." in text
    partly = separated | {"comm": [0.3, 0.55]}
    assert "they overlap for comm vs independent" in ordering_sentence(means, partly)
    wrong = ordering_sentence({"full": 0.4, "comm": 0.5, "independent": 0.3}, separated)
    assert "NOT the order" in wrong
    assert "not available" in ordering_sentence(means, {m: None for m in means})
    overlap = {m: [0.0, 1.0] for m in means}
    assert "not established" in ordering_sentence(means, overlap)


def test_parking_sentence_branches() -> None:
    assert "learned the loophole" in parking_sentence(0.04, 0.8, 0.9, 0.7)
    assert "not clearly hacked" in parking_sentence(0.5, 0.8, 0.2, 0.1)
    assert "With the arrival reward" not in parking_sentence(0.04, None, 0.9, 0.7)


def test_dial_sentence_branches() -> None:
    assert "clearly helps" in dial_sentence("full", (0.8, [0.7, 0.9]), (0.5, [0.4, 0.6]))
    assert "DIAL hurts" in dial_sentence("full", (0.5, [0.4, 0.6]), (0.8, [0.7, 0.9]))
    assert "no clear effect" in dial_sentence("full", (0.6, [0.5, 0.7]), (0.55, [0.5, 0.6]))


def test_generalisation_sentence_branches() -> None:
    assert "largely specific" in generalisation_sentence(0.8, 0.3, 1.0)
    assert "more than on the training map" in generalisation_sentence(0.3, 0.6, 1.0)
    assert "transfers" in generalisation_sentence(0.5, 0.45, 1.0)
    assert generalisation_sentence(None, 0.45, 1.0).endswith("(oracle: 100.0 %).")
