"""Report sections 2.1-2.6: the environment, reward, architecture, hyperparameters,
training curves and final success rates."""

from __future__ import annotations

import numpy as np
from report_inputs import MODES, missing_note
from report_layout import Block, Bullets, Heading, Note, Paragraph, Table
from report_problem2_data import (
    P2,
    SECTIONS,
    TARGETS,
    TRAIN_COMMAND,
    Stat,
    _figure,
    _source_note,
)
from report_rules import (
    dial_sentence,
    join_words,
    num,
    ordering_sentence,
    parking_sentence,
    pct,
    target_check,
)


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
