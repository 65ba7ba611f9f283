"""The Markdown comparison of Problem 2's evaluation (``comparison_table.md``), built from
the results dict of ``analysis.pipeline.evaluate_all``. (The course's
``create_evaluation_report`` is in ``evaluate.py``.)"""

from __future__ import annotations

from typing import Any

from analysis.arrivals import DECOMPOSITION
from analysis.failures import FAILURE_KINDS


def _stat(stat: dict | None, digits: int = 3) -> str:
    """``mean [low, high]`` of a seed-statistics dict, ``–`` if empty."""
    if not stat or stat.get("mean") is None:
        return "–"
    low, high = stat["ci95"]
    return f"{stat['mean']:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def _per_seed(stat: dict) -> str:
    return ", ".join("–" if v is None else f"{v:.2f}" for v in stat["per_seed"])


def _decomposed(stat: dict) -> str:
    """A share of failed episodes pooled over seeds where there is one, else the seed mean."""
    return _number(stat["pooled"], 3) if "pooled" in stat else _stat(stat)


def _number(value: float | None, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _mode_rows(experiment: dict) -> list[list[str]]:
    rows = []
    for entry in experiment["modes"].values():
        greedy, eps = entry["greedy"], entry["eps"]
        rows.append(
            [
                entry["label"],
                _stat(greedy["success_rate"]),
                f"{greedy['success_rate']['iqm']:.3f}",
                _stat(eps["success_rate"]),
                f"{eps['success_rate']['iqm']:.3f}",
                f"{_per_seed(greedy['success_rate'])} / {_per_seed(eps['success_rate'])}",
                _stat(eps["mean_steps_to_success"], 1),
                _stat(eps["mean_return"], 2),
            ]
        )
    return rows


def _baseline_rows(experiment: dict) -> list[list[str]]:
    rows = []
    for name, summary in experiment["baselines"].items():
        explored = summary.get("eps", summary)  # the oracle is also run at ε; the others greedy
        rate, rate_eps = f"{summary['success_rate']:.3f}", f"{explored['success_rate']:.3f}"
        steps = _number(explored["mean_steps_to_success"], 1)
        rows.append(
            [name, rate, rate, rate_eps, rate_eps, "–", steps, _number(explored["mean_return"])]
        )
    return rows


SUCCESS_HEADER = [
    "policy",
    "success greedy, mean [95 % CI]",
    "IQM",
    "success ε, mean [95 % CI]",
    "IQM",
    "per seed (greedy / ε)",
    "steps to success (ε)",
    "return (ε)",
]


def success_section(performance: dict) -> list[str]:
    """Main map: every mode, the per_step and no_dial study rows, random and oracle."""
    experiments = performance["experiments"]
    protocol = performance["protocol"]
    main = experiments.get("main") or next(iter(experiments.values()))
    rows = _mode_rows(main)
    for name in ("per_step", "no_dial"):
        if name in experiments:
            rows += _mode_rows(experiments[name])
    rows += _baseline_rows(main)
    return [
        f"## Success on the training map (map seed {main['map_seed']}, target "
        f"{tuple(main['target'])})",
        "",
        f"{protocol['episodes_per_seed']} fixed test episodes per trained seed (start cells "
        f"from seed {protocol['evaluation_seed']}); ε = {protocol['conditions']['eps']}. "
        "Mean over training seeds with a 95 % percentile bootstrap CI over seeds; IQM = "
        "interquartile mean over seeds. Returns are under the assignment's reward (+10 both "
        "on the target, +2 on each step with exactly one on it, −0.1 otherwise), whatever "
        "reward the agents learned from.",
        "",
        *_table(SUCCESS_HEADER, rows),
        "",
    ]


def failure_section(performance: dict) -> list[str]:
    rows = []
    for name, experiment in performance["experiments"].items():
        for entry in experiment["modes"].values():
            for condition in ("greedy", "eps"):
                failures = entry[condition]["failures"]
                failed = 1 - entry[condition]["success_rate"]["mean"]
                shares = [_number(failures[kind]["pooled"]) for kind in FAILURE_KINDS]
                rows.append([name, entry["label"], condition, f"{failed:.3f}", *shares])
    definitions = performance["protocol"]["failure_definitions"]
    notes = [f"- **{kind}**: {text}" for kind, text in definitions.items()]
    header = ["experiment", "mode", "condition", "failed", *FAILURE_KINDS]
    return [
        "## How episodes fail (share of the failed episodes of all seeds together)",
        "",
        *notes,
        "",
        *_table(header, rows),
        "",
    ]


def message_section(communication: dict) -> list[str]:
    rows, verdicts = [], []
    for name, experiment in communication["experiments"].items():
        for entry in experiment["modes"].values():
            if "causal" not in entry:
                continue
            causal = entry["causal"]
            for condition in ("greedy", "eps"):
                test = causal[condition]
                rows.append(
                    [
                        name,
                        entry["label"],
                        condition,
                        _number(test["real"]["mean"], 3),
                        _number(test["shuffled"]["mean"], 3),
                        _number(test["zeroed"]["mean"], 3),
                        _stat(test["real_minus_shuffled"]),
                        _per_seed(test["real_minus_shuffled"]),
                    ]
                )
            verdicts.append(f"- {name}, {entry['label']}: {causal['verdict']}")
    if not rows:
        return []
    header = [
        "experiment",
        "mode",
        "condition",
        "real",
        "shuffled",
        "zeroed",
        "real − shuffled [95 % CI]",
        "per seed",
    ]
    return [
        "## Is the message used? (success with the real, a shuffled and a zeroed message)",
        "",
        *_table(header, rows),
        "",
        *verdicts,
        "",
    ]


def generalization_section(generalization: dict | None) -> list[str]:
    if not generalization:
        return []
    maps = generalization["maps"]
    modes = list(next(iter(maps.values()))["modes"])
    header = ["map seed", "target", "oracle (steps)", "random"]
    header += [f"{mode} greedy / ε" for mode in modes]
    rows = []
    for map_seed, entry in maps.items():
        oracle = entry["oracle"]
        row = [map_seed, str(tuple(entry["target"]))]
        row.append(f"{oracle['success_rate']:.2f} ({_number(oracle['mean_steps_to_success'], 1)})")
        row.append(f"{entry['random']['success_rate']:.3f}")
        for mode in modes:
            stats = entry["modes"][mode]
            row.append(f"{stats['greedy']['mean']:.3f} / {stats['eps']['mean']:.3f}")
        rows.append(row)
    means = generalization["mean_over_maps"]
    rows.append(
        ["mean", "", "", ""]
        + [f"{_stat(means[m]['greedy'])} / {_stat(means[m]['eps'])}" for m in modes]
    )
    return [
        f"## Generalisation: models trained on map {generalization['trained_map_seed']} on "
        f"unseen map seeds 0–{len(maps) - 1}",
        "",
        f"{generalization['episodes_per_map']} episodes per model and map; mean over "
        "training seeds.",
        "",
        *_table(header, rows),
        "",
    ]


def intervention_section(communication: dict) -> list[str]:
    """Main experiment: Δsuccess of every intervention with its CI, and the verdicts."""
    modes = communication["experiments"].get("main", {}).get("modes", {})
    rows, verdicts = [], []
    for mode, entry in modes.items():
        for channel, test in entry.get("interventions", {}).items():
            for condition in ("greedy", "eps"):
                deltas = test[condition]["delta_success"]
                real = _stat(test[condition]["success"]["real"])
                for kind, delta in deltas.items():
                    rows.append([mode, channel, condition, real, kind, _stat(delta)])
                verdicts.append(
                    f"- {mode}, {channel}, {condition}: **{test[condition]['verdict']}**: "
                    f"{test[condition]['verdict_text']}."
                )
    if not rows:
        return []
    header = [
        "mode",
        "channel",
        "condition",
        "success (real)",
        "intervention",
        "Δ success [95 % CI over seeds]",
    ]
    return [
        "## What the agents use of each input channel (main experiment)",
        "",
        *_table(header, rows),
        "",
        *verdicts,
        "",
    ]


def decomposition_section(performance: dict) -> list[str]:
    main = performance["experiments"].get("main") or next(iter(performance["experiments"].values()))
    keys = tuple(DECOMPOSITION)  # the measures in their defined order
    rows = [
        [mode, condition, f"{1 - entry[condition]['success_rate']['mean']:.3f}"]
        + [_decomposed(entry[condition]["failure_decomposition"][key]) for key in keys]
        for mode, entry in main["modes"].items()
        for condition in ("greedy", "eps")
    ]
    notes = [f"- **{k}**: {v}" for k, v in performance["protocol"]["failure_decomposition"].items()]
    return [
        "## Why episodes fail: navigation or timing (main experiment; shares of failed "
        "episodes: all seeds' failed episodes together; staying shares: mean over seeds "
        "[95 % CI])",
        "",
        *notes,
        "",
        *_table(["mode", "condition", "failed", *keys], rows),
        "",
    ]


def measures_section(communication: dict) -> list[str]:
    modes = communication["experiments"].get("main", {}).get("modes", {})
    rows = []
    for mode, entry in modes.items():
        for bins, values in entry.get("measures", {}).items():
            for measure, senders in values.items():
                rows.append([mode, bins, measure, _stat(senders["A"]), _stat(senders["B"])])
    if not rows:
        return []
    return [
        "## Communication measures (Lowe et al. 2019; bits, greedy test episodes)",
        "",
        "The independent mode's partner never reads the message: its values are the "
        "reference for the estimator's bias (its CIC is 0 by construction).",
        "",
        *_table(["mode", "bins", "measure", "sender A [95 % CI]", "sender B [95 % CI]"], rows),
        "",
    ]


def differences_section(performance: dict) -> list[str]:
    """Every experiment's pairwise mode differences, and which are established."""
    rows = []
    for name, experiment in performance["experiments"].items():
        for conditions in experiment.get("mode_differences", {}).values():
            for condition, d in conditions.items():
                low, high = d["ci95"]
                rows.append(
                    [
                        name,
                        f"{d['first']} − {d['second']}",
                        condition,
                        f"{d['mean']:+.3f} [{low:+.3f}, {high:+.3f}]",
                        "[{:+.3f}, {:+.3f}]".format(*d["ci95_seeds_only"]),
                        "**yes**" if d["established"] else "no",
                    ]
                )
    if not rows:
        return []
    text = performance["protocol"].get("mode_differences", "")
    return [
        "## Differences between modes (success, first − second)",
        "",
        text[0].upper() + text[1:] + ".",
        "",
        *_table(
            [
                "experiment",
                "difference",
                "condition",
                "mean [95 % CI]",
                "CI, episodes fixed",
                "established (CI excludes 0)",
            ],
            rows,
        ),
        "",
    ]


def held_out_section(generalization: dict | None) -> list[str]:
    held_out = (generalization or {}).get("held_out")
    if not held_out:
        return []
    rows = [
        [name, _stat(stat), _stat(stat), "–"] for name, stat in held_out["success_rate"].items()
    ]
    for mode, conditions in held_out.get("modes", {}).items():
        rows.append(
            [f"{mode} (trained on map {held_out['trained_map_seed']})"]
            + [_stat(conditions[c]["over_maps"]) for c in ("greedy", "eps")]
            + [_stat(conditions["eps"]["over_seeds"])]
        )
    return [
        f"## Held-out maps: {len(held_out['map_seeds'])} maps never used for any choice "
        f"({held_out['episodes_per_map']} episodes each)",
        "",
        "Baselines are greedy (their two columns agree). CI over maps, except the last "
        "column (each seed's mean over the maps, CI over seeds).",
        "",
        *_table(
            [
                "policy",
                "success greedy [95 % CI over maps]",
                f"success ε = {held_out['epsilon']} [CI over maps]",
                "success ε [CI over seeds]",
            ],
            rows,
        ),
        "",
    ]


def format_report(results: dict[str, Any]) -> str:
    """Markdown of every section (``comparison_table.md``)."""
    performance = results["performance"]
    sections = [success_section(performance), differences_section(performance)]
    sections += [failure_section(performance), decomposition_section(performance)]
    if "communication" in results:
        sections.append(message_section(results["communication"]))
        sections.append(intervention_section(results["communication"]))
        sections.append(measures_section(results["communication"]))
    sections.append(generalization_section(results.get("generalization")))
    sections.append(held_out_section(results.get("generalization")))
    title = ["# Problem 2: evaluation of the trained agents", ""]
    return "\n".join(title + [line for section in sections for line in section])
