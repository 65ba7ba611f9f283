"""Report sections 2.7-2.11: the message, strategies, failures, other maps, limits."""

from __future__ import annotations

import numpy as np
from report_inputs import MODES, missing_note
from report_layout import Block, Bullets, Heading, Note, Paragraph, Table
from report_problem2_data import (
    CONDITIONS,
    EVAL_COMMAND,
    FAILURE_KINDS,
    FEATURES,
    P2,
    SECTIONS,
    TARGETS,
    TRAIN_COMMAND,
    Stat,
    _figure,
    _source_note,
)
from report_rules import (
    generalisation_sentence,
    join_words,
    message_effect,
    num,
    pct,
    pct_ci,
    target_check,
)


def _feature_means(entry: dict) -> dict[str, dict[str, float]]:
    """agent -> feature -> mean Pearson r over seeds (features with no r left out)."""
    collected: dict[str, dict[str, list[float]]] = {}
    for seed_entry in entry.get("per_seed", {}).values():
        for agent, features in seed_entry.get("correlations", {}).items():
            for name, item in features.items():
                if item.get("r") is not None:
                    collected.setdefault(agent, {}).setdefault(name, []).append(item["r"])
    return {a: {f: float(np.mean(v)) for f, v in fs.items()} for a, fs in collected.items()}


def message_use(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[7])]
    blocks.append(
        Paragraph(
            "Setting the message to zero at test time is out of distribution (zero only "
            "occurs at reset), so the causal test replaces each arriving message by the one "
            "that arrived at the same step in another test episode, which keeps the "
            "distribution of messages and breaks only their link to the situation. A mode "
            "uses its message if success drops when the message is shuffled, with a 95 % CI "
            "of the drop (over seeds) above zero."
        )
    )
    experiment = (p2.communication or {}).get("experiments", {}).get("main")
    if not experiment:
        return blocks + [Note(missing_note("evaluation_results/communication_analysis.json",
                                           EVAL_COMMAND))]  # fmt: skip
    rows, verdicts = [], []
    for mode in ("comm", "full"):
        causal = experiment.get("modes", {}).get(mode, {}).get("causal")
        if not causal:
            continue
        for condition in CONDITIONS:
            test = causal[condition]
            diff = Stat.of(test["real_minus_shuffled"])
            ci = diff.ci or test["real_minus_shuffled"].get("episode_ci95")
            rows.append((mode, "greedy" if condition == "greedy" else "ε = 0.05",
                         pct(Stat.of(test["real"]).mean), pct(Stat.of(test["shuffled"]).mean),
                         pct(Stat.of(test["zeroed"]).mean), pct_ci(diff.mean, ci)))  # fmt: skip
            if condition == "eps" and diff.mean is not None and ci:
                verdicts.append(f"{mode}: " + message_effect(diff.mean, ci)[1] + ".")
    blocks.append(
        Table(
            ("mode", "condition", "real", "shuffled", "zeroed", "real − shuffled [95 % CI]"),
            tuple(rows),
            (0.8, 1.0, 0.8, 0.9, 0.8, 2.0),
            "Causal message test on the training map (communication_analysis.json).",
        )
    )
    blocks.append(Paragraph("At ε = 0.05 — " + " ".join(verdicts)))
    blocks += message_meaning(p2, experiment)
    return blocks


def message_meaning(p2: P2, experiment: dict) -> list[Block]:
    rows, strongest = [], []
    for mode in ("comm", "full"):
        entry = experiment.get("modes", {}).get(mode)
        if not entry:
            continue
        for agent, features in _feature_means(entry).items():
            rows.append((mode, agent, *(num(features.get(f), 2) for f in FEATURES)))
            if features:
                best = max(features, key=lambda f: abs(features[f]))
                strongest.append(
                    f"{mode}, agent {agent}: {best.replace('_', ' ')} (r = {features[best]:+.2f})"
                )
    blocks: list[Block] = []
    if rows:
        blocks.append(
            Table(
                (
                    "mode",
                    "agent",
                    "on target",
                    "sees target",
                    "distance to target",
                    "distance between agents",
                    "time step",
                ),
                tuple(rows),
                (0.7, 0.6, 0.9, 0.9, 1.1, 1.2, 0.9),
                "What the message encodes: Pearson correlation of the message sent with "
                "features of the sender's situation (greedy test episodes, mean over seeds).",
            )  # fmt: skip
        )
        blocks.append(
            Paragraph(
                "The feature most correlated with the message is "
                + "; ".join(strongest)
                + ". A correlation of magnitude above about 0.5 means the message is largely a "
                "signal of that feature; small correlations everywhere mean it carries little "
                "that these features describe."
            )
        )
    blocks.append(
        _figure(
            p2.results.p2("evaluation_results/comm_heatmap.png"),
            "Figure 2.2 — Mean message emitted by each agent from each cell (greedy test "
            "episodes of each mode's best seed).",
            "evaluation_results/comm_heatmap.png",
            EVAL_COMMAND,
            4.2,
        )
    )
    return blocks


def strategies(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[8])]
    experiment = p2.experiment("main")
    oracle = p2.baseline("oracle")
    if experiment and oracle:
        parts = []
        for mode, entry in experiment.get("modes", {}).items():
            steps = Stat.of(entry["eps"]["mean_steps_to_success"]).mean
            if steps is not None:
                parts.append(f"{mode} {steps:.1f}")
        blocks.append(
            Paragraph(
                "Successful episodes take on average "
                + join_words(parts)
                + f" steps at ε = 0.05, against {num(oracle['mean_steps_to_success'], 1)} for "
                "the shortest-path oracle: the agents search for the target rather than walk "
                "to it, since neither sees further than its 3×3 patch. Without the distance "
                "input (independent, comm) an agent cannot tell whether its partner is near; "
                "with it, the agents can wait for or move towards each other. The figure shows "
                "one successful and one failed test episode per mode; animations are in "
                "problem2/results/evaluation_results/episode_<mode>.gif."
            )
        )
    else:
        blocks.append(Note(missing_note("evaluation_results/performance.json", EVAL_COMMAND)))
    blocks.append(
        _figure(
            p2.results.p2("evaluation_results/trajectories.png"),
            "Figure 2.3 — Paths of both agents in a representative successful and failed "
            "episode for each mode (start cells, target and obstacles marked).",
            "evaluation_results/trajectories.png",
            EVAL_COMMAND,
            6.0,
        )
    )
    return blocks


def failures(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[9])]
    experiment = p2.experiment("main")
    if not experiment:
        return blocks + [Note(missing_note("evaluation_results/performance.json", EVAL_COMMAND))]
    definitions = (p2.performance or {}).get("protocol", {}).get("failure_definitions", {})
    if definitions:
        blocks.append(
            Bullets(
                tuple(
                    f"{k}: {v}" for k, v in definitions.items() if k in (*FAILURE_KINDS, "window")
                )
            )
        )
    rows, dominant = [], []
    for mode, entry in experiment.get("modes", {}).items():
        for condition in CONDITIONS:
            shares = {k: Stat.of(entry[condition]["failures"].get(k)).mean for k in FAILURE_KINDS}
            failed = 1 - (Stat.of(entry[condition]["success_rate"]).mean or 0)
            rows.append((mode, "greedy" if condition == "greedy" else "ε = 0.05", pct(failed),
                         *(pct(shares[k]) for k in FAILURE_KINDS)))  # fmt: skip
            present = {k: v for k, v in shares.items() if v is not None}
            if present and condition == "greedy":
                top = max(present, key=present.get)
                dominant.append(f"{mode}: {top} ({pct(present[top])} of failures)")
    blocks.append(
        Table(
            ("mode", "condition", "failed", "swapping", "parked", "looping", "other"),
            tuple(rows),
            (1.0, 1.0, 0.8, 0.9, 0.9, 0.9, 0.9),
            "Share of episodes that fail and, among them, the share of each kind (mean over "
            "seeds; performance.json).",
        )
    )
    blocks.append(
        Paragraph(
            "The most common greedy failure is " + "; ".join(dominant) + ". Stuck patterns "
            "(swapping, parked, looping) are what a memoryless deterministic policy does when "
            "two situations look identical to it; the exploration of ε = 0.05 breaks many of "
            "them, which is why the ε-greedy policies fail less."
        )
    )
    return blocks


def _panel_maps(p2: P2) -> list[int]:
    maps = set()
    for name in (p2.performance or {}).get("experiments", {}):
        if name.startswith("map_panel/map"):
            maps.add(int(name.rsplit("map", 1)[1]))
    panel = p2.results.p2("studies/map_panel")
    if panel.is_dir():
        maps |= {int(p.name[3:]) for p in panel.iterdir() if p.name[3:].isdigit()}
    return sorted(maps)


def map_panel(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[10])]
    maps = _panel_maps(p2)
    rows, holds, total = [], 0, 0
    any_eval = True
    for map_seed in maps:
        table, from_eval = p2.success(f"map_panel/map{map_seed}")
        if not table:
            continue
        any_eval &= from_eval
        oracle = p2.baseline("oracle", map_seed) or {}
        target = (p2.baselines or {}).get("maps", {}).get(str(map_seed), {}).get("target")
        means = {m: table[m]["eps"].mean for m in MODES if m in table}
        if len(means) == 3:
            total += 1
            holds += int(means["full"] >= means["comm"] >= means["independent"])
        rows.append((str(map_seed), str(tuple(target)) if target else "–",
                     *(table[m]["eps"].text() if m in table else "–" for m in MODES),
                     num(oracle.get("mean_steps_to_success"), 1)))  # fmt: skip
    if rows:
        blocks.append(
            Paragraph(
                "Whether the ordering of the three configurations is a property of the method "
                f"or of one map: the three modes were trained and tested on {len(rows)} other "
                f"maps. The order full ≥ comm ≥ independent holds on {holds} of {total} maps."
            )
        )
        blocks.append(
            Table(
                ("map seed", "target", "independent (ε)", "comm (ε)", "full (ε)", "oracle steps"),
                tuple(rows),
                (0.7, 0.7, 1.5, 1.5, 1.5, 0.8),
                "Map panel: success at ε = 0.05 on each map. " + _source_note(any_eval),
            )
        )
    else:
        blocks.append(Note(missing_note("the map-panel study (studies/map_panel)", TRAIN_COMMAND)))
    blocks += generalisation(p2)
    return blocks


def generalisation(p2: P2) -> list[Block]:
    gen = p2.generalization
    if not gen or not gen.get("maps"):
        return [Note(missing_note("evaluation_results/generalization.json", EVAL_COMMAND))]
    maps = gen["maps"]
    modes = [m for m in MODES if m in gen.get("mean_over_maps", {})]
    rows = []
    for seed, entry in maps.items():
        rows.append((seed, str(tuple(entry["target"])), pct(entry["oracle"]["success_rate"]),
                     *(pct(Stat.of(entry["modes"][m]["eps"]).mean) for m in modes)))  # fmt: skip
    means = gen["mean_over_maps"]
    rows.append(("mean", "", pct(np.mean([e["oracle"]["success_rate"] for e in maps.values()])),
                 *(Stat.of(means[m]["eps"]).text() for m in modes)))  # fmt: skip
    main, _ = p2.success("main")
    blocks: list[Block] = [
        Paragraph(
            f"Generalisation: the models trained on map {gen.get('trained_map_seed')} were run, "
            f"unchanged, on {len(maps)} map seeds they never saw "
            f"({gen.get('episodes_per_map')} episodes per model and map). "
            + " ".join(
                f"{m}: "
                + generalisation_sentence(
                    main.get(m, {}).get("eps").mean if m in main else None,
                    Stat.of(means[m]["eps"]).mean or 0.0,
                    float(np.mean([e["oracle"]["success_rate"] for e in maps.values()])),
                )
                for m in modes
            )
        ),
        Table(
            ("map seed", "target", "oracle", *(f"{m} (ε)" for m in modes)),
            tuple(rows),
            (0.7, 0.7, 0.7, *(1.5 for _ in modes)),
            "Success of the training-map models on unseen maps (generalization.json).",
        ),
    ]
    return blocks


def limits(p2: P2) -> list[Block]:
    items: list[str] = []
    table, from_eval = p2.success("main")
    for mode, condition, target in TARGETS:
        value = table.get(mode, {}).get(condition)
        if value and value.mean is not None and value.mean < target - 1e-9:
            items.append(target_check(f"Target missed — {mode}", value.mean, target))
    experiment = (p2.communication or {}).get("experiments", {}).get("main", {})
    for mode in ("comm", "full"):
        causal = experiment.get("modes", {}).get(mode, {}).get("causal")
        if causal:
            diff = causal["eps"]["real_minus_shuffled"]
            ci = diff.get("ci95") if diff.get("n", 0) > 1 else diff.get("episode_ci95")
            if (
                diff.get("mean") is not None
                and ci
                and message_effect(diff["mean"], ci)[0] != "helps"
            ):
                items.append(
                    f"In {mode} mode the causal test finds no benefit of the real message on "
                    "the training map; whatever the agents gain there does not come from the "
                    "message."
                )
    full = table.get("full", {}).get("eps")
    if full and len([v for v in full.per_seed if v is not None]) > 1:
        values = [v for v in full.per_seed if v is not None]
        items.append(
            f"Seeds differ a lot: the full configuration ranges from {pct(min(values))} to "
            f"{pct(max(values))} across {len(values)} seeds, so a handful of seeds gives wide CIs."
        )
    if not from_eval:
        items.append("The evaluation script's results were not available; CIs are missing.")
    items += [
        "The agents see only a 3×3 patch and have no memory: they cannot remember where they "
        "have searched, which limits success on maps whose target is not found by a simple rule.",
        "All results are for one grid size and a short training budget on a 2-core CPU. The "
        "settings were chosen by a small manual search on the default map (learning rate, "
        "target-update period, number of parallel environments, budget, checkpoint selection, "
        "learning-rate annealing; full mode, two seeds that are not among the reported ones), "
        "so the default map is not a fully held-out test; the map panel is.",
        "The reward was changed from the literal reading (section 2.2); results under the "
        "literal reward are reported only for the full configuration.",
    ]
    return [Heading(SECTIONS[11]), Bullets(tuple(items))]
