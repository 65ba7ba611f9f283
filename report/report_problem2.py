"""The Problem 2 part of the report: blocks built from ``problem2/results``.

Success rates come from ``evaluation_results/performance.json`` (``python evaluate.py``:
1000 fixed test episodes per trained seed, mean over seeds with a 95 % bootstrap CI) when
it exists; before that, from the trainer's own final test (``*_final.json``, same episode
protocol) with the range over seeds instead of a CI, and the text says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from report_inputs import MODES, Results, missing_note
from report_layout import Block, Bullets, Figure, Heading, Note, Paragraph, Table
from report_rules import (
    dial_sentence,
    generalisation_sentence,
    join_words,
    message_effect,
    num,
    ordering_sentence,
    parking_sentence,
    pct,
    pct_ci,
    target_check,
)

TRAIN_COMMAND = "make problem2"
EVAL_COMMAND = "cd problem2 && python evaluate.py"
CONDITIONS = ("greedy", "eps")
# Success targets set by the learning issue (ε = 0.05 unless marked greedy); not results.
TARGETS = (("full", "eps", 0.85), ("full", "greedy", 0.75), ("comm", "eps", 0.55),
           ("independent", "eps", 0.40))  # fmt: skip
FEATURES = ("on_target", "sees_target", "target_distance", "agent_distance", "time_step")
FAILURE_KINDS = ("swapping", "parked", "looping", "other")
SECTIONS = (
    "Problem 2: Two communicating DQN agents",
    "2.1 Environment",
    "2.2 Reward choice",
    "2.3 Architecture and DIAL message training",
    "2.4 Hyperparameters",
    "2.5 Training curves",
    "2.6 Final success rates",
    "2.7 Is the message used?",
    "2.8 Learned strategies",
    "2.9 Failure analysis",
    "2.10 Map panel and generalisation",
    "2.11 Limits and honest negatives",
)


@dataclass
class Stat:
    """A success rate (or other quantity) over training seeds."""

    mean: float | None
    ci: list[float] | None = None  # 95 % bootstrap CI over seeds (None: not computed)
    per_seed: list[float] = field(default_factory=list)

    @classmethod
    def of(cls, entry: dict | None) -> Stat:
        """From an ``analysis_stats.seed_statistics`` dict."""
        if not entry:
            return cls(None)
        return cls(entry.get("mean"), entry.get("ci95"), list(entry.get("per_seed") or []))

    @classmethod
    def values(cls, values: list[float]) -> Stat:
        return cls(float(np.mean(values)) if values else None, None, list(values))

    def text(self) -> str:
        """``73.4 % [68.0, 78.1]``, or with the seed range ``73.4 % (range 60.0–80.0)``."""
        if self.ci or len(self.per_seed) < 2:
            return pct_ci(self.mean, self.ci)
        present = [v for v in self.per_seed if v is not None]
        return f"{pct(self.mean)} (range {100 * min(present):.1f}–{100 * max(present):.1f})"


@dataclass
class P2:
    """Every Problem 2 input, loaded once (None / empty where missing)."""

    results: Results
    hyper: dict | None
    grid: np.ndarray | None
    baselines: dict | None
    performance: dict | None
    communication: dict | None
    generalization: dict | None
    notes: list[str] = field(default_factory=list)

    @classmethod
    def load(cls, results: Results) -> P2:
        grid_json = results.json(results.p2("agent_models/map.json"))
        evaluation = results.p2("evaluation_results")
        return cls(
            results,
            results.json(results.p2("agent_models/hyperparameters.json")),
            np.array(grid_json["grid"]) if grid_json and "grid" in grid_json else None,
            results.json(evaluation / "baselines.json"),
            results.json(evaluation / "performance.json"),
            results.json(evaluation / "communication_analysis.json"),
            results.json(evaluation / "generalization.json"),
        )

    def root(self, experiment: str) -> Path:
        return (
            self.results.problem2
            if experiment == "main"
            else self.results.p2(f"studies/{experiment}")
        )

    def experiment(self, name: str) -> dict | None:
        if not self.performance:
            return None
        return self.performance.get("experiments", {}).get(name)

    def success(self, name: str = "main") -> tuple[dict[str, dict[str, Stat]], bool]:
        """mode -> condition -> success Stat of experiment ``name``, and whether the numbers
        come from ``performance.json`` (True) or the trainer's final tests (False)."""
        experiment = self.experiment(name)
        if experiment and experiment.get("modes"):
            table = {
                mode: {c: Stat.of(entry[c]["success_rate"]) for c in CONDITIONS}
                for mode, entry in experiment["modes"].items()
            }
            return table, True
        finals = self.results.final_runs(self.root(name))
        table = {
            mode: {c: Stat.values([r[c]["success_rate"] for r in runs]) for c in CONDITIONS}
            for mode, runs in finals.items()
        }
        return table, False

    def baseline(self, name: str, map_seed: int | None = None) -> dict | None:
        """Random or oracle summary on a map (default: the training map)."""
        key = str(map_seed if map_seed is not None else (self.hyper or {}).get("map_seed", 641))
        experiment = self.experiment("main")
        if map_seed is None and experiment and name in experiment.get("baselines", {}):
            return experiment["baselines"][name]
        if self.baselines:
            return self.baselines.get("maps", {}).get(key, {}).get(name)
        return None


def _source_note(from_evaluation: bool) -> str:
    if from_evaluation:
        return (
            "Numbers: evaluation_results/performance.json (mean over training seeds, 95 % "
            "percentile-bootstrap CI over seeds in brackets)."
        )
    return (
        "Numbers: the trainer's final test of each seed (training_logs/*_final.json, 1000 "
        "episodes); evaluate.py's CIs were not available, so the range over seeds is shown."
    )


def _figure(path: Path, caption: str, what: str, command: str, height: float = 4.6) -> Block:
    found = Results.png(path)
    return Figure(found, caption, height) if found else Note(missing_note(what, command))


# --------------------------------------------------------------------------- sections
def environment(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[1])]
    hyper = p2.hyper or {}
    if p2.grid is None:
        blocks.append(Note(missing_note("agent_models/map.json", TRAIN_COMMAND)))
        size, obstacles, target = None, None, None
    else:
        size = p2.grid.shape
        obstacles = int((p2.grid == 1).sum())
        target = tuple(int(v) for v in np.argwhere(p2.grid == 2)[0])
    grid_text = f"{size[0]}×{size[1]}" if size else "10×10"
    blocks.append(
        Paragraph(
            f"Two agents, A and B, move on a {grid_text} grid"
            + (f" with {obstacles} obstacles and one target at {target}" if size else "")
            + f" (map seed {hyper.get('map_seed', '–')}, drawn once and kept for training "
            "and testing). Each step both choose one of five actions (up, down, left, right, "
            "stay) and emit a message in [0, 1]. An agent observes an 11-number vector: its "
            "3×3 neighbourhood (free, obstacle, target or off-grid; the partner is not "
            "drawn), the partner's last message, and the normalised distance between the two "
            "agents. Success means both agents stand on the target at the same step within "
            f"{hyper.get('max_steps', 50)} steps; each episode places both agents on random "
            "distinct free cells."
        )
    )
    blocks.append(
        Paragraph(
            "Three configurations are compared: independent (message and distance masked to "
            "zero), comm (message only; distance masked) and full (both). The mask is one "
            "function applied wherever a network sees an observation, and each exported "
            "TorchScript model carries its own mask."
        )
    )
    random, oracle = p2.baseline("random"), p2.baseline("oracle")
    if random and oracle:
        blocks.append(
            Paragraph(
                f"On this map a uniformly random policy succeeds in {pct(random['success_rate'])} "
                f"of episodes, and a full-information shortest-path oracle in "
                f"{pct(oracle['success_rate'])} after {num(oracle['mean_steps_to_success'], 1)} "
                "steps on average: these bracket what the learners can reach."
            )
        )
    else:
        blocks.append(Note(missing_note("evaluation_results/baselines.json", TRAIN_COMMAND)))
    return blocks


def reward_choice(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[2])]
    blocks.append(
        Paragraph(
            "The assignment pays +2 'while exactly one agent is on the target', every step, "
            "+10 when both are on it and −0.1 per step. Read literally this is hackable: one "
            "agent parks on the target and collects +2 per step for the rest of the episode "
            "while the other stays away, since finishing the task ends the income. We "
            "therefore train with the arrival reward: +10 and the end of the episode when both "
            "stand on the target; +2 when an agent reaches the target for the first time in "
            "the episode (in place of that step's −0.1); −0.1 otherwise. The 50-step cut-off "
            "is not a true ending, so the TD target bootstraps through it."
        )
    )
    finals = p2.results.final_runs(p2.root("per_step")).get("full", [])
    if not finals:
        return blocks + [Note(missing_note("the per_step reward study (studies/per_step)",
                                           TRAIN_COMMAND))]  # fmt: skip
    eps = [r["eps"] for r in finals]
    main, _ = p2.success("main")
    arrival = main.get("full", {}).get("eps")
    sentence = parking_sentence(
        float(np.mean([e["success_rate"] for e in eps])),
        arrival.mean if arrival else None,
        float(np.mean([e["share_episodes_one_never_arrives"] for e in eps])),
        float(np.mean([e["share_steps_one_on_target"] for e in eps])),
    )
    blocks.append(
        Paragraph(
            f"To measure this, the full configuration was also trained with the literal "
            f"reward ({len(finals)} seeds, final weights kept, since selecting checkpoints by "
            f"success would select against parking). {sentence}"
        )
    )
    rows = []
    main_finals = p2.results.final_runs(p2.root("main")).get("full", [])
    for label, runs in (
        ("literal per-step reward", finals),
        ("arrival reward (ours)", main_finals),
    ):
        if runs:
            e = [r["eps"] for r in runs]
            rows.append((
                label, str(len(runs)),
                pct(np.mean([x["success_rate"] for x in e])),
                pct(np.mean([x["share_steps_one_on_target"] for x in e])),
                pct(np.mean([x["share_episodes_one_never_arrives"] for x in e])),
            ))  # fmt: skip
    blocks.append(
        Table(
            (
                "full configuration",
                "seeds",
                "success",
                "steps with exactly one on target",
                "episodes where one never arrives",
            ),
            tuple(rows),
            (1.8, 0.6, 0.9, 1.4, 1.4),
            "Parking under the two rewards (trainer's final test, 1000 episodes per seed, "
            "ε = 0.05, mean over seeds).",
        )  # fmt: skip
    )
    return blocks


def architecture(p2: P2) -> list[Block]:
    hyper = p2.hyper or {}
    hidden = hyper.get("hidden_dim", "–")
    kind = "dueling" if hyper.get("dueling") else "plain"
    blocks: list[Block] = [Heading(SECTIONS[3])]
    blocks.append(
        Paragraph(
            f"Each agent has its own {kind} Q-network: one hidden layer of {hidden} ReLU units "
            "on the 11-number observation, a linear head with five Q-values and a message head "
            "(one logit, sigmoid to [0, 1]). The two agents are independent learners: each is "
            "trained on its own TD error from a shared replay of joint transitions, with a "
            "Double-DQN target from a periodically copied target network, the Huber loss "
            "summed over both agents, gradient-norm clipping"
            + (" and prioritised replay." if hyper.get("prioritized") else " and uniform replay.")
        )
    )
    blocks.append(
        Paragraph(
            "Under plain independent Q-learning the message head receives no gradient at all: "
            "the message only enters the partner's input, and the partner's TD loss is not "
            "differentiated through it. We train it as in DIAL (Foerster et al., 2016). Each "
            "stored transition also keeps the partner's previous observation; at update time "
            "the arriving message is recomputed by the partner's online network with gradient, "
            f"with Gaussian noise (σ = {hyper.get('comm_noise', '–')}) on its logit, and "
            "spliced into element 9 of the receiver's input. The receiver's TD loss then "
            "trains the sender's message head; the next-state message of the TD target comes "
            "from the partner's target network. The noise pushes the sender towards messages "
            "that survive it, i.e. towards nearly binary signals."
        )
    )
    blocks += dial_study(p2)
    return blocks


def dial_study(p2: P2) -> list[Block]:
    frozen, frozen_eval = p2.success("no_dial")
    if not frozen:
        return [Note(missing_note("the untrained-message study (studies/no_dial)", TRAIN_COMMAND))]
    main, main_eval = p2.success("main")
    sentences = [
        dial_sentence(mode, (main[mode]["eps"].mean, main[mode]["eps"].ci),
                      (frozen[mode]["eps"].mean, frozen[mode]["eps"].ci))
        for mode in ("comm", "full")
        if mode in frozen and mode in main
    ]  # fmt: skip
    source = "with CIs" if main_eval and frozen_eval else "CIs not available (trainer's tests)"
    return [
        Paragraph(
            "Is DIAL needed? The comm and full configurations were retrained with the message "
            f"head left untrained (success at ε = 0.05; {source}): " + " ".join(sentences)
        )
    ]


HYPER_ROWS = (
    ("total_steps", "environment steps per run (all parallel envs together)"),
    ("num_envs", "parallel environments"),
    ("lr", "Adam learning rate (start)"),
    ("lr_end_factor", "learning rate at the end, as a fraction of the start (linear)"),
    ("batch_size", "minibatch of joint transitions"),
    ("buffer_size", "replay capacity (joint transitions)"),
    ("learning_starts", "transitions collected before the first update"),
    ("updates_per_step", "gradient updates per vector step"),
    ("gamma", "discount"),
    ("epsilon_start", "ε at the start"),
    ("epsilon_end", "ε at the end of the schedule"),
    ("epsilon_decay", "fraction of the run over which ε decays linearly"),
    ("target_update", "updates between hard target-network copies"),
    ("hidden_dim", "hidden units (one layer)"),
    ("max_grad_norm", "gradient-norm clip"),
    ("comm_noise", "std of the DIAL noise on the message logit"),
    ("comm_learning", "message training"),
    ("reward_mode", "reward"),
    ("eval_interval", "env steps between validation evaluations"),
    ("eval_episodes", "validation episodes per evaluation"),
    ("keep_best", "keep the best validation checkpoint"),
    ("final_eval_episodes", "test episodes per seed at the end"),
    ("num_seeds", "training seeds per mode"),
    ("seed", "first seed"),
)


def hyperparameters(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[4])]
    if not p2.hyper:
        return blocks + [Note(missing_note("agent_models/hyperparameters.json", TRAIN_COMMAND))]
    rows = tuple((name, str(p2.hyper[name]), text) for name, text in HYPER_ROWS if name in p2.hyper)
    blocks.append(
        Table(
            ("parameter", "value", "meaning"),
            rows,
            (1.4, 0.9, 3.6),
            "Hyperparameters of the main experiment (agent_models/hyperparameters.json); "
            "the studies change only the entries named in their sections.",
        )  # fmt: skip
    )
    timing = p2.results.json(p2.results.p2("training_logs/timing.json"))
    if timing:
        seconds = list(timing.values())
        blocks.append(
            Paragraph(
                f"One run took {min(seconds):.0f}–{max(seconds):.0f} s of wall time "
                f"({len(seconds)} runs, two at a time on the 2-core CPU; timing.json)."
            )
        )
    return blocks


def _last_validation(logs: list[dict[str, np.ndarray]], column: str) -> Stat:
    values = []
    for table in logs:
        series = table[column][~np.isnan(table[column])]
        if series.size:
            values.append(float(series[-1]))
    return Stat.values(values)


def training_curves(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[5])]
    logs = p2.results.training_logs(p2.root("main"))
    if logs:
        steps = max(int(np.nanmax(t["env_steps"])) for runs in logs.values() for t in runs)
        parts = [
            f"{mode} {_last_validation(runs, 'eval_success_eps').text()}"
            for mode, runs in logs.items()
        ]
        blocks.append(
            Paragraph(
                f"Each run trains for {steps:,} environment steps. Every "
                f"{(p2.hyper or {}).get('eval_interval', '–')} steps the greedy and ε = 0.05 "
                f"policies are evaluated on {(p2.hyper or {}).get('eval_episodes', '–')} fixed "
                "validation episodes; the figure shows the mean over seeds with a band. At the "
                f"last evaluation the ε = 0.05 validation success is {join_words(parts)} (mean "
                "over seeds, range). The rolling success of the training episodes over-counts "
                "short successful episodes and is not used as a result; the final numbers "
                "(section 2.6) come from separate test episodes."
            )
        )
    else:
        blocks.append(Note(missing_note("the training logs (training_logs/*.csv)", TRAIN_COMMAND)))
    blocks.append(
        _figure(
            p2.results.p2("training_logs/training_curves.png"),
            "Figure 2.1 — Average return and success rate against environment steps for the "
            "three configurations (mean over seeds, shaded band).",
            "training_logs/training_curves.png",
            TRAIN_COMMAND,
            5.0,
        )
    )
    return blocks


def final_success(p2: P2) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[6])]
    table, from_eval = p2.success("main")
    if not table:
        return blocks + [Note(missing_note("the final test results", TRAIN_COMMAND))]
    experiment = p2.experiment("main") or {}
    rows = []
    for mode in MODES:
        if mode not in table:
            continue
        entry = experiment.get("modes", {}).get(mode, {})
        steps = Stat.of(entry.get("eps", {}).get("mean_steps_to_success")).mean
        if steps is None:  # trainer's final tests
            found = [
                r["eps"]["mean_steps_to_success"]
                for r in p2.results.final_runs(p2.root("main")).get(mode, [])
            ]
            found = [v for v in found if v is not None]
            steps = float(np.mean(found)) if found else None
        per_seed = ", ".join(f"{100 * v:.0f}" for v in table[mode]["eps"].per_seed if v is not None)
        rows.append((mode, table[mode]["greedy"].text(), table[mode]["eps"].text(), per_seed,
                     num(steps, 1)))  # fmt: skip
    for name in ("random", "oracle"):
        summary = p2.baseline(name)
        if summary:
            rate = pct(summary["success_rate"])
            rows.append((name, rate, rate, "–", num(summary.get("mean_steps_to_success"), 1)))
    blocks.append(
        Table(
            (
                "policy",
                "success, greedy",
                "success, ε = 0.05",
                "per seed (ε, %)",
                "steps to success (ε)",
            ),
            tuple(rows),
            (1.1, 1.7, 1.7, 1.5, 1.0),
            "Success on the training map. " + _source_note(from_eval),
        )  # fmt: skip
    )
    means = {m: table[m]["eps"].mean for m in table if table[m]["eps"].mean is not None}
    cis = {m: table[m]["eps"].ci for m in table}
    blocks.append(
        Paragraph(
            "At ε = 0.05, "
            + ordering_sentence(means, cis)[0].lower()
            + ordering_sentence(means, cis)[1:]
        )
    )
    checks = [
        target_check(f"{mode} ({'greedy' if c == 'greedy' else 'ε = 0.05'})",
                     table[mode][c].mean if mode in table else None, target)
        for mode, c, target in TARGETS
    ]  # fmt: skip
    blocks.append(Paragraph("Against the targets set for this work:"))
    blocks.append(Bullets(tuple(checks)))
    gaps = [
        f"{mode} {100 * (table[mode]['eps'].mean - table[mode]['greedy'].mean):+.1f}"
        for mode in table
        if table[mode]["eps"].mean is not None and table[mode]["greedy"].mean is not None
    ]
    blocks.append(
        Paragraph(
            "A little exploration helps a memoryless policy: success at ε = 0.05 minus greedy "
            f"success is {join_words(gaps)} points. A deterministic policy that maps the same "
            "observation to the same action can cycle forever; random actions break the cycle."
            if all(float(g.split()[-1]) > 0 for g in gaps)
            else "Success at ε = 0.05 minus greedy success is "
            f"{join_words(gaps)} points: exploration does not uniformly help."
        )
    )
    return blocks


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
        "All results are for one grid size and a short training budget on a 2-core CPU; no "
        "hyperparameter search was done beyond the prototype settings.",
        "The reward was changed from the literal reading (section 2.2); results under the "
        "literal reward are reported only for the full configuration.",
    ]
    return [Heading(SECTIONS[11]), Bullets(tuple(items))]


def problem2_blocks(results: Results) -> list[Block]:
    """Every block of the Problem 2 part."""
    p2 = P2.load(results)
    blocks: list[Block] = [Heading(SECTIONS[0], level=1)]
    sections = (environment, reward_choice, architecture, hyperparameters, training_curves,
                final_success, message_use, strategies, failures, map_panel, limits)  # fmt: skip
    for section in sections:
        blocks += section(p2)
    return blocks


def headline(results: Results) -> dict[str, Any]:
    """Headline numbers for the title page (None where missing)."""
    p2 = P2.load(results)
    table, _ = p2.success("main")
    return {mode: table[mode]["eps"].mean for mode in table}
