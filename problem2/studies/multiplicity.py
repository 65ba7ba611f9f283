"""Multiplicity: Holm's correction over each family of tests the report calls established.

Three families, all at the epsilon test condition:

* **the panel's effects**: on each map of the panel, the four contrasts of the modes' test
  success (message, distance, both, interaction; ``studies/panel.py``);
* **the memory panel's effects**: the same four contrasts on each map of the panel for agents
  with one step of memory (``studies/one_step/panel.py``, ``channel_effects_with_memory``),
  tested as the panel's are; a family of its own, since its agents are separate training runs;
* **the interventions**: every replacement of a channel at test time (another episode's value
  at the same step, a random step, shuffled in time, constants), on the main experiment's map
  and on every panel map, for each configuration that sees the channel.

A test's p-value comes from the committed per-seed success rates alone (the JSON holds no
per-episode outcomes): a percentile bootstrap over the training seeds, two-sided, the smallest
level at which the bootstrap interval of the same kind as the report's excludes 0. For an
effect the seeds of each mode are redrawn independently (they are separate training runs); for
an intervention the per-seed changes are redrawn (the same agents on the same episodes, with
and without the replacement). Holm's step-down correction then holds the family-wise error
rate at ``ALPHA`` within each family.

    cd problem2 && python -m studies.multiplicity   # results/studies/panel/multiplicity.json

It also redraws the panel's figure (``panel_effects.png``), whose filled markers are the effects
that survive the correction.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
from analysis.interventions import channel_verdict

from studies.panel_outputs import plot_effects

ALPHA = 0.05
RESAMPLES = 20_000
SEED = 0
RESULTS = Path(__file__).resolve().parent.parent / "results"
PANEL = RESULTS / "studies" / "panel" / "panel.json"
INTERVENTIONS = RESULTS / "evaluation_results" / "interventions.json"
MEMORY_PANEL = RESULTS / "studies" / "memory_panel" / "memory_panel.json"
OUTPUT = RESULTS / "studies" / "panel" / "multiplicity.json"
CONDITION = "eps"
# The (configuration, channel) pairs whose channel is replaced at test time.
PROBED = (("comm", "message"), ("distance", "distance"), ("full", "message"), ("full", "distance"))


def bootstrap_p_value(
    groups: Mapping[str, Sequence[float]],
    coefficients: Mapping[str, float],
    n_resamples: int = RESAMPLES,
    seed: int = SEED,
) -> float:
    """Two-sided percentile-bootstrap p-value of the contrast sum_g c_g mean(groups[g]) = 0.

    Each resample redraws the values of every group of ``coefficients`` with replacement,
    independently between groups; p = 2 min(P(contrast* <= 0), P(contrast* >= 0)), each
    share counted as (1 + hits) / (1 + resamples) so that p is never 0, and capped at 1.
    A contrast that no resample brings to 0 gets the smallest p the resamples can show."""
    rng = np.random.default_rng(seed)
    total = np.zeros(n_resamples)
    for group in sorted(coefficients):
        values = np.asarray(groups[group], dtype=np.float64)
        if values.size == 0:
            raise ValueError(f"group {group!r} has no values")
        picks = rng.integers(0, values.size, size=(n_resamples, values.size))
        total += coefficients[group] * values[picks].mean(axis=1)
    total = np.round(total, 12)  # a sum of equal rates is 0, not 1e-17
    below = (1 + np.count_nonzero(total <= 0)) / (1 + n_resamples)
    above = (1 + np.count_nonzero(total >= 0)) / (1 + n_resamples)
    return float(min(1.0, 2 * min(below, above)))


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values, in the order given: the k-th smallest p (k from
    0) is multiplied by (m - k), and the adjusted values are made non-decreasing in that
    order and capped at 1. A test is rejected at level alpha when its adjusted p <= alpha."""
    p = np.asarray(p_values, dtype=np.float64)
    m = p.size
    order = np.argsort(p, kind="stable")
    adjusted = np.empty(m)
    running = 0.0
    for k, index in enumerate(order):
        running = max(running, min(1.0, (m - k) * p[index]))
        adjusted[index] = running
    return adjusted.tolist()


def _family(tests: list[dict[str, Any]], alpha: float) -> dict[str, Any]:
    """Adds ``p_holm`` and ``rejected`` to each test; the family's summary."""
    adjusted = holm([t["p"] for t in tests])
    for test, p in zip(tests, adjusted, strict=True):
        test["p_holm"] = p
        test["rejected"] = bool(p <= alpha)
    return {
        "tests": len(tests),
        "rejected_uncorrected": sum(t["p"] <= alpha for t in tests),
        "rejected": sum(t["rejected"] for t in tests),
    }


def panel_effects(panel: dict[str, Any], alpha: float = ALPHA) -> dict[str, Any]:
    """The panel's effect family: maps.<seed>.<effect> with mean, p, p_holm, rejected and
    verdict (gain or loss where rejected, else unclear), and the family summary."""
    per_map = {
        key: (
            {mode: s[CONDITION]["per_seed"] for mode, s in entry["success"].items()},
            entry["effects"][CONDITION],
        )
        for key, entry in panel["maps"].items()
    }
    return _effect_family(per_map, alpha)


def memory_panel_effects(memory_panel: dict[str, Any], alpha: float = ALPHA) -> dict[str, Any]:
    """The memory panel's effect family, built as ``panel_effects``: the per-seed success of
    the agents with one step of memory, each effect's coefficients from
    ``channel_effects_with_memory``."""
    per_map = {}
    for key, entry in memory_panel["maps"].items():
        found_at = entry["conditions"][CONDITION]
        rates = {mode: s["memory"]["per_seed"] for mode, s in found_at["success"].items()}
        per_map[key] = (rates, found_at["channel_effects_with_memory"])
    return _effect_family(per_map, alpha)


def _effect_family(per_map: dict[str, tuple[dict, dict]], alpha: float) -> dict[str, Any]:
    """One Holm family over every map's effects: ``per_map`` maps a map's key to (per-seed
    success by mode, its effects with mean, established and coefficients)."""
    tests, maps = [], {}
    for key, (rates, effects) in per_map.items():
        maps[key] = {}
        for effect, found in effects.items():
            test = {
                "mean": found["mean"],
                "uncorrected_established": found["established"],
                "p": bootstrap_p_value(rates, found["coefficients"]),
            }
            maps[key][effect] = test
            tests.append(test)
    summary = _family(tests, alpha)
    for effects in maps.values():
        for test in effects.values():
            sign = "gain" if test["mean"] > 0 else "loss"
            test["verdict"] = sign if test["rejected"] else "unclear"
    return {"summary": summary, "maps": maps}


def _probe_tests(deltas: dict[str, dict]) -> dict[str, dict[str, Any]]:
    """One test per replacement kind from its per-seed changes of success."""
    return {
        kind: {
            "mean": stat["mean"],
            "p": bootstrap_p_value({"delta": stat["per_seed"]}, {"delta": 1.0}),
        }
        for kind, stat in deltas.items()
    }


def corrected_verdict(tests: dict[str, dict[str, Any]]) -> str:
    """The verdict of ``analysis.interventions.channel_verdict`` with "lowers success"
    meaning a rejected test (after Holm) with a negative mean change."""
    losses = {
        k: {"ci95": [-1.0, -1.0] if t["rejected"] and t["mean"] < 0 else [0.0, 0.0]}
        for k, t in tests.items()
    }
    return channel_verdict(losses)


def interventions_family(
    panel: dict[str, Any], interventions: dict[str, Any], alpha: float = ALPHA
) -> dict[str, Any]:
    """The intervention family: cases ``main`` (the assignment's map) and panel map seeds,
    each <mode>.<channel> with its tests per kind and its corrected verdict."""
    cases: dict[str, dict] = {"main": {}}
    tests = []
    for mode, channels in interventions["experiments"]["main"].items():
        for channel, conditions in channels.items():
            found = _probe_tests(conditions[CONDITION]["delta_success"])
            cases["main"].setdefault(mode, {})[channel] = {
                "uncorrected_verdict": conditions[CONDITION]["verdict"],
                "tests": found,
            }
            tests.extend(found.values())
    for key, entry in panel["maps"].items():
        cases[key] = {}
        for mode, channel in PROBED:
            probe = entry["behaviour"]["modes"][mode]["interventions"].get(channel)
            if probe is None:
                continue
            found = _probe_tests(probe[CONDITION]["delta_success"])
            cases[key].setdefault(mode, {})[channel] = {
                "uncorrected_verdict": probe[CONDITION]["verdict"],
                "tests": found,
            }
            tests.extend(found.values())
    summary = _family(tests, alpha)
    for modes in cases.values():
        for channels in modes.values():
            for case in channels.values():
                case["verdict"] = corrected_verdict(case["tests"])
    return {"summary": summary, "cases": cases}


def multiplicity(
    panel: dict[str, Any],
    interventions: dict[str, Any],
    memory_panel: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The families' tests; the memory panel's family only when its results are given."""
    result = {
        "protocol": {
            "correction": "Holm (step-down), family-wise error rate",
            "alpha": ALPHA,
            "condition": CONDITION,
            "p_value": "two-sided percentile bootstrap over training seeds (per-seed rates)",
            "resamples": RESAMPLES,
            "seed": SEED,
        },
        "panel_effects": panel_effects(panel),
        "interventions": interventions_family(panel, interventions),
    }
    if memory_panel is not None:
        result["memory_panel_effects"] = memory_panel_effects(memory_panel)
    return result


def main(argv: list[str] | None = None) -> None:
    use_reproducible_matmul()  # an entry point's first step, as everywhere
    make_console_safe()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    panel = json.loads(PANEL.read_text(encoding="utf-8"))
    interventions = json.loads(INTERVENTIONS.read_text(encoding="utf-8"))
    memory_panel = (
        json.loads(MEMORY_PANEL.read_text(encoding="utf-8")) if MEMORY_PANEL.exists() else None
    )
    result = multiplicity(panel, interventions, memory_panel)
    write_json_atomic(args.output, result)
    plot_effects(PANEL.parent / "panel_effects.png", panel, result["panel_effects"]["maps"])
    for family in ("panel_effects", "interventions", "memory_panel_effects"):
        if family not in result:
            continue
        s = result[family]["summary"]
        print(
            f"{family}: {s['rejected']} of {s['tests']} rejected after Holm "
            f"({s['rejected_uncorrected']} before)"
        )


if __name__ == "__main__":
    main()
