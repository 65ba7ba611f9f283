"""The Problem 1 part of the report: blocks built from ``problem1/results``."""

from __future__ import annotations

import numpy as np
from report_inputs import Results, missing_note
from report_layout import Block, Bullets, Figure, Heading, Note, Paragraph, Table
from report_rules import (
    cell_name,
    drift_discussion,
    hazard_value_loss,
    join_words,
    sweep_comparison,
    sweep_cost,
    verification_sentence,
)

P1_COMMAND = "make problem1"
# The problem statement (INTERFACES.md), not results.
SPEC = {
    "size": 5,
    "start": (0, 0),
    "goal": (4, 4),
    "obstacles": ((1, 2), (2, 1)),
    "penalties": ((3, 3), (3, 0)),
    "goal_reward": 10.0,
    "penalty_reward": -5.0,
    "step_cost": -0.1,
    "prob_intended": 0.8,
    "prob_drift": 0.1,
    "max_steps": 50,
}
SECTIONS = (
    "Problem 1: Dynamic programming on a stochastic gridworld",
    "1.1 Environment and layout",
    "1.2 Iterations to convergence",
    "1.3 Optimal value function and policy",
    "1.4 Q-functions",
    "1.5 Convergence of VI and QI",
    "1.6 Stochasticity study",
    "1.7 Verification",
)


def _figure(results: Results, name: str, caption: str, max_height: float = 4.6) -> Block:
    path = results.png(results.p1(f"visualizations/{name}"))
    if path is None:
        return Note(missing_note(f"the figure visualizations/{name}", P1_COMMAND))
    return Figure(path, caption, max_height)


def _cell_symbol(row: int, col: int) -> str:
    cell = (row, col)
    if cell == SPEC["start"]:
        return "S (start)"
    if cell == SPEC["goal"]:
        return "G (goal)"
    if cell in SPEC["obstacles"]:
        return "# (obstacle)"
    if cell in SPEC["penalties"]:
        return "P (penalty)"
    return "·"


def environment(summary: dict | None) -> list[Block]:
    size = SPEC["size"]
    rows = tuple((str(r), *(_cell_symbol(r, c) for c in range(size))) for r in range(size))
    gamma = f"γ = {summary['gamma']}" if summary else "γ (see summary.json)"
    text = (
        f"The agent moves on a {size}×{size} grid from the start {SPEC['start']} to the goal "
        f"{SPEC['goal']} (positions are (row, column), row 0 at the top). Each of the four "
        f"actions (up, right, down, left) moves in the intended direction with probability "
        f"{SPEC['prob_intended']} and drifts to either perpendicular direction with "
        f"probability {SPEC['prob_drift']} each; a move into the outer wall or an obstacle "
        f"leaves the agent in place. The reward depends on the cell entered: "
        f"{SPEC['goal_reward']:+g} for the goal (terminal), {SPEC['penalty_reward']:+g} for a "
        f"penalty cell (not terminal) and {SPEC['step_cost']:+g} otherwise; episodes are cut "
        f"after {SPEC['max_steps']} steps. We solve the discounted problem with {gamma}."
    )
    return [
        Heading(SECTIONS[1]),
        Paragraph(text),
        Table(
            ("row", *(f"col {c}" for c in range(size))),
            rows,
            (0.5, 1, 1, 1, 1, 1),
            "Layout (the course's code layout; an older docstring listed other cells).",
            size=8.5,
        ),
        Paragraph(
            "Both solvers share one tabular model of the MDP — for every state and action "
            "the three possible next states, their probabilities and rewards — and one "
            "vectorised Bellman backup. Values start at zero; one iteration is one full "
            "synchronous sweep over all states, and a solver stops at the first sweep whose "
            "sup-norm change falls below ε."
        ),
    ]


def iterations(summary: dict | None) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[2])]
    if summary is None:
        return blocks + [Note(missing_note("problem1/results/summary.json", P1_COMMAND))]
    vi, qi = summary["value_iteration"], summary["q_iteration"]
    rows = []
    for name, entry in (("Value Iteration", vi), ("Q-Iteration", qi)):
        rows.append((
            name,
            str(entry["iterations"]),
            "yes" if entry["converged"] else "NO",
            f"{entry['final_change']:.2e}",
            f"{entry['bellman_residual']:.2e}",
            f"{entry['v_start']:.4f}",
            f"{entry['seconds_per_sweep'] * 1e6:.0f}",
        ))  # fmt: skip
    agree = (
        "The two greedy policies agree in every state"
        if summary["policies_agree"]
        else "The two greedy policies DISAGREE in some states"
    )
    blocks += [
        Paragraph(
            f"With γ = {summary['gamma']} and ε = {summary['epsilon']:g}, Value Iteration "
            f"converged after {vi['iterations']} sweeps and Q-Iteration after "
            f"{qi['iterations']}. Both give V(start) = {summary['v_start']:.4f}; the largest "
            f"difference between the two value functions is "
            f"{summary['max_value_difference_vi_qi']:.1e}. {agree}."
        ),
        Table(
            (
                "algorithm",
                "sweeps",
                "converged",
                "last change",
                "Bellman residual",
                "V(start)",
                "µs / sweep",
            ),
            tuple(rows),
            (1.5, 0.8, 0.9, 1, 1.1, 0.9, 0.9),
            "Convergence of both solvers (problem1/results/summary.json). The time per sweep "
            "is wall-clock time and varies between runs.",
        ),  # fmt: skip
    ]
    return blocks


def intended_path(policy) -> list[tuple[int, int]]:
    """Cells visited from the start when every move of ``policy`` succeeds (stops at the
    goal, at a blocked move or when a cell repeats)."""
    moves = ((-1, 0), (0, 1), (1, 0), (0, -1))
    size = SPEC["size"]
    cell, path = SPEC["start"], [SPEC["start"]]
    while cell != SPEC["goal"]:
        dr, dc = moves[int(policy[cell[0] * size + cell[1]])]
        nxt = (cell[0] + dr, cell[1] + dc)
        if not (0 <= nxt[0] < size and 0 <= nxt[1] < size) or nxt in SPEC["obstacles"]:
            break
        if nxt in path:
            break
        cell = nxt
        path.append(cell)
    return path


def value_and_policy(results: Results, summary: dict | None) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[3])]
    values = results.npz(results.p1("value_function.npz"))
    policy = results.npz(results.p1("optimal_policy.npz"))
    if values is not None and policy is not None:
        v, pi = values["values"], policy["policy"]
        penalties = [r * SPEC["size"] + c for r, c in SPEC["penalties"]]
        around = [s for s in range(len(v)) if v[s] != 0]
        lowest = min(around, key=lambda s: v[s])
        path = intended_path(pi)
        hazards = {tuple(h) for h in SPEC["penalties"]}
        brushes = [
            c for c in path if any(abs(c[0] - h[0]) + abs(c[1] - h[1]) == 1 for h in hazards)
        ]
        route = " → ".join(f"({r}, {c})" for r, c in path)
        ends = "reaches the goal" if path[-1] == SPEC["goal"] else "does NOT reach the goal"
        beside = (
            f"on its way, {join_words([str(c) for c in brushes])} "
            f"{'is' if len(brushes) == 1 else 'are'} next to a penalty cell"
            if brushes
            else "no cell on it is next to a penalty cell"
        )
        blocks.append(
            Paragraph(
                f"V* ranges from {v[lowest]:.2f} at {cell_name(lowest)} to {max(v):.2f} next "
                "to the goal. The penalty cells hold (the −5 is paid on entering them) "
                f"{join_words([f'{v[s]:.2f} at {cell_name(s)}' for s in penalties])}. "
                f"Following the policy with every move succeeding, the route from the start "
                f"is {route} ({len(path) - 1} moves); it {ends}, and {beside}."
            )
        )
    else:
        blocks.append(Note(missing_note("the arrays value_function.npz / optimal_policy.npz",
                                        P1_COMMAND)))  # fmt: skip
    blocks.append(
        _figure(
            results,
            "value_heatmap.png",
            "Figure 1.1 — V* as a heatmap with the value in each cell and the greedy action "
            "as an arrow; obstacles, penalty cells, start and goal are marked.",
        )
    )
    blocks.append(
        _figure(
            results,
            "policy_arrows.png",
            "Figure 1.2 — The optimal policy: the greedy action of V* in every free cell.",
            4.0,
        )
    )
    return blocks


def q_functions(results: Results) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[4])]
    q = results.npz(results.p1("q_function.npz"))
    if q is not None:
        qv = q["q_values"]
        spread = qv.max(axis=1) - qv.min(axis=1)
        state = int(spread.argmax())
        blocks.append(
            Paragraph(
                "Q*(s, a) for each action is shown below. The actions differ most where a "
                f"wrong move is expensive: at {cell_name(state)} the best and the worst "
                f"action differ by {spread[state]:.2f}; the median gap over all non-terminal "
                f"states is {float(np.median(spread[spread > 0])):.2f}."
            )
        )
    blocks.append(
        _figure(
            results,
            "q_functions.png",
            "Figure 1.3 — Q*(s, a) per action (four panels, same colour scale).",
            5.2,
        )
    )
    return blocks


def convergence(results: Results, summary: dict | None) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[5])]
    if summary is not None:
        vi, qi = summary["value_iteration"], summary["q_iteration"]
        blocks.append(Paragraph(sweep_comparison(vi["iterations"], qi["iterations"])))
        blocks.append(Paragraph(sweep_cost(vi["seconds_per_sweep"], qi["seconds_per_sweep"])))
    else:
        blocks.append(Note(missing_note("problem1/results/summary.json", P1_COMMAND)))
    blocks.append(
        _figure(
            results,
            "convergence.png",
            "Figure 1.4 — Sup-norm change per sweep for VI and QI on a log axis, with the "
            "γ^k contraction bound.",
            3.2,
        )
    )
    blocks.append(
        _figure(
            results,
            "comparison.png",
            "Figure 1.5 — VI and QI side by side: values and policies, and their difference.",
            2.6,
        )
    )
    return blocks


def stochasticity(results: Results) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[6])]
    study = results.json(results.p1("stochasticity_study.json"))
    if not study or not study.get("settings"):
        return blocks + [Note(missing_note("problem1/results/stochasticity_study.json",
                                           P1_COMMAND))]  # fmt: skip
    settings = sorted(study["settings"], key=lambda s: s["drift"])
    blocks.append(
        Paragraph(
            "The same problem was solved for drift probabilities "
            f"{join_words([format(s['drift'], 'g') for s in settings])} per side (intended "
            "probability 1 − 2·drift). A 'detour state' is a state where the noisy optimal "
            "action would be strictly worse than the best action without drift."
        )
    )
    rows = tuple(
        (
            f"{s['drift']:g}",
            f"{s['prob_intended']:g}",
            str(s["iterations"]),
            f"{s['v_start']:.3f}",
            f"{s['expected_steps']:.1f}",
            f"{s['expected_penalty_visits']:.3f}",
            ", ".join(cell_name(c) for c in s["detour_states"]) or "none",
        )
        for s in settings
    )
    blocks.append(
        Table(
            (
                "drift",
                "intended",
                "sweeps",
                "V(start)",
                "E[steps]",
                "E[penalty entries]",
                "detour states",
            ),
            rows,
            (0.6, 0.7, 0.6, 0.8, 0.8, 1.1, 2.6),
            "Stochasticity study (stochasticity_study.json); expected values under the "
            "optimal policy from the start.",
        )  # fmt: skip
    )
    sentences = drift_discussion(settings)
    deterministic = settings[0]["values"]
    reference = next(
        (s for s in settings if abs(s["drift"] - study.get("reference_drift", 0.1)) < 1e-9),
        settings[-1],
    )
    penalties = [r * SPEC["size"] + c for r, c in SPEC["penalties"]]
    worst, near = hazard_value_loss(deterministic, reference["values"], penalties)
    where = join_words([cell_name(s) for s in worst])
    sentences.append(
        f"Noise lowers the values most where a drift does most harm: at drift "
        f"{reference['drift']:g} the largest losses against the drift-free values are at "
        f"{where}, "
        + ("next to or on a penalty cell." if near else "which are not next to a penalty cell.")
    )
    sentences.append(
        "The number of sweeps also grows with drift: noise slows the propagation of the goal "
        "reward, so more of the contraction is needed before the changes fall below ε "
        f"({settings[0]['iterations']} sweeps at drift {settings[0]['drift']:g}, "
        f"{settings[-1]['iterations']} at {settings[-1]['drift']:g})."
        if settings[-1]["iterations"] > settings[0]["iterations"]
        else "The number of sweeps does not grow with drift here."
    )
    blocks.append(Paragraph(" ".join(sentences)))
    blocks.append(
        _figure(
            results,
            "stochasticity_policies.png",
            "Figure 1.6 — Optimal values and policies for each drift level (shared colour scale).",
            4.4,
        )
    )
    blocks.append(
        _figure(
            results,
            "stochasticity_start_value.png",
            "Figure 1.7 — V(start), expected episode length and penalty entries against drift.",
            3.0,
        )
    )
    return blocks


def verification(summary: dict | None) -> list[Block]:
    blocks: list[Block] = [Heading(SECTIONS[7])]
    if summary is None or "verification" not in summary:
        return blocks + [Note(missing_note("the verification in summary.json", P1_COMMAND))]
    blocks.append(
        Paragraph(
            "The solution is checked without trusting the solvers: "
            + verification_sentence(summary["verification"])
        )
    )
    blocks.append(
        Bullets(
            (
                "The test suite (tests/problem1) repeats these checks, checks the transition "
                "model against sampled env.step outcomes, and checks that without drift the "
                "policy walks a shortest path that avoids the penalty cells.",
                "VI and QI are independent routes to the same fixed point; their value "
                f"functions differ by at most {summary['max_value_difference_vi_qi']:.1e}.",
            )
        )
    )
    return blocks


def problem1_blocks(results: Results) -> list[Block]:
    """Every block of the Problem 1 part."""
    summary = results.json(results.p1("summary.json"))
    blocks: list[Block] = [Heading(SECTIONS[0], level=1)]
    blocks += environment(summary)
    blocks += iterations(summary)
    blocks += value_and_policy(results, summary)
    blocks += q_functions(results)
    blocks += convergence(results, summary)
    blocks += stochasticity(results)
    blocks += verification(summary)
    return blocks
