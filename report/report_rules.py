"""Number formatting and the rules that turn measured numbers into interpreting sentences.

Every function here is pure: the numbers come in, a sentence (or a verdict) comes out, and
the wording follows the numbers (a difference is called real only when its confidence
interval excludes zero, and so on). ``tests/report/test_report_rules.py`` covers each branch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

ACTION_NAMES = ("up", "right", "down", "left")
GRID_SIZE = 5


# --------------------------------------------------------------------------- formatting
def pct(value: float | None, digits: int = 1) -> str:
    """``0.734`` -> ``'73.4 %'``; None -> ``'–'``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{100 * value:.{digits}f} %"


def pct_ci(mean: float | None, ci: Sequence[float] | None, digits: int = 1) -> str:
    """``'73.4 % [68.0, 78.1]'`` (percentages; the CI is left out if missing)."""
    if mean is None:
        return "–"
    if not ci:
        return pct(mean, digits)
    return f"{pct(mean, digits)} [{100 * ci[0]:.{digits}f}, {100 * ci[1]:.{digits}f}]"


def num(value: float | None, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}"


def cell_name(state: int, size: int = GRID_SIZE) -> str:
    """State index -> ``'(row, col)'``."""
    return f"({state // size}, {state % size})"


def join_words(words: Sequence[str]) -> str:
    """``['a', 'b', 'c']`` -> ``'a, b and c'``."""
    words = list(words)
    if len(words) <= 1:
        return "".join(words)
    return ", ".join(words[:-1]) + " and " + words[-1]


# --------------------------------------------------------------------------- Problem 1
def sweep_comparison(vi_sweeps: int, qi_sweeps: int) -> str:
    """Why Value Iteration and Q-Iteration need the same (or a different) number of sweeps."""
    if vi_sweeps == qi_sweeps:
        return (
            f"VI and QI need the same number of sweeps ({vi_sweeps}). This is expected: "
            "starting from zero, the Q-iterate after k sweeps is exactly the one-step "
            "look-ahead of the V-iterate after k − 1 sweeps, so max_a Q_k = V_k and both "
            "sequences contract at the same rate γ in the sup norm. QI's change at sweep k is "
            "at most γ times VI's change at sweep k − 1, so the two stopping tests fire at the "
            "same or at adjacent sweeps."
        )
    more, fewer = ("QI", "VI") if qi_sweeps > vi_sweeps else ("VI", "QI")
    return (
        f"{more} needs {abs(qi_sweeps - vi_sweeps)} more sweep(s) than {fewer} "
        f"({vi_sweeps} for VI, {qi_sweeps} for QI). Both contract at rate γ, but the "
        "stopping test measures the change of different quantities (V versus every Q(s, a)), "
        "so the threshold can be crossed one sweep apart."
    )


def sweep_cost(vi_seconds: float, qi_seconds: float) -> str:
    """Compare the measured time per sweep (both are O(S·A) with three outcomes)."""
    ratio = qi_seconds / vi_seconds if vi_seconds > 0 else math.inf
    head = (
        f"A sweep took {vi_seconds * 1e6:.0f} µs for VI and {qi_seconds * 1e6:.0f} µs for QI. "
        "Both do the same work per sweep — for each of the S·A state-action pairs, an "
        "expectation over three outcomes — so the asymptotic cost is O(S·A) for both; QI "
        "stores S·A numbers instead of S."
    )
    if 1 / 1.5 <= ratio <= 1.5:
        return head + " The measured costs agree within a factor 1.5, as the analysis predicts."
    slower = "QI" if ratio > 1 else "VI"
    return head + (
        f" Here {slower} was {max(ratio, 1 / ratio):.1f}× slower per sweep; at these "
        "micro-second scales that is dominated by interpreter overhead, not by the algorithm."
    )


def verification_sentence(verification: dict) -> str:
    """Pass/fail wording of the solver-independent checks in ``summary.json``."""
    error = verification["policy_evaluation_max_error"]
    bound = verification["residual_bound"]
    mc = verification["monte_carlo"]
    low, high = mc["ci99"]
    parts = []
    if verification["within_bound"]:
        parts.append(
            f"Evaluating the greedy policy exactly by a linear solve gives values within "
            f"{error:.2e} of V*, inside the Bellman-residual bound {bound:.2e}, so the policy "
            "is optimal up to that tolerance."
        )
    else:
        parts.append(
            f"The exact evaluation of the greedy policy differs from V* by {error:.2e}, MORE "
            f"than the residual bound {bound:.2e}: the solution fails this check."
        )
    verdict = "contains" if mc["contains_v_start"] else "does NOT contain"
    parts.append(
        f"{mc['episodes']} Monte-Carlo episodes run with env.step return {mc['mean_return']:.3f} "
        f"on average; the 99 % interval [{low:.3f}, {high:.3f}] {verdict} V(start)."
    )
    return " ".join(parts)


def drift_discussion(settings: list[dict]) -> list[str]:
    """Sentences on how the drift probability changes the optimal policy and its value
    (``settings``: the entries of ``stochasticity_study.json`` in increasing drift)."""
    settings = sorted(settings, key=lambda s: s["drift"])
    first, last = settings[0], settings[-1]
    sentences = []
    values = [s["v_start"] for s in settings]
    monotone = all(b <= a + 1e-12 for a, b in zip(values, values[1:], strict=False))
    trend = "falls monotonically" if monotone else "changes non-monotonically"
    sentences.append(
        f"V(start) {trend} from {first['v_start']:.2f} at drift {first['drift']:g} to "
        f"{last['v_start']:.2f} at drift {last['drift']:g}, and the expected number of steps "
        f"to the goal grows from {first['expected_steps']:.1f} to {last['expected_steps']:.1f}."
    )
    changed = [s for s in settings if s["detour_states"]]
    if not changed:
        sentences.append(
            "At none of the drift levels studied does the optimal policy deviate from a "
            "shortest path; noise only lowers the values."
        )
    else:
        onset = changed[0]
        cells = join_words([cell_name(c) for c in onset["detour_states"]])
        sentences.append(
            f"Up to drift {settings[settings.index(onset) - 1]['drift']:g} the policy stays on a "
            f"shortest path; from drift {onset['drift']:g} it takes detours "
            f"({len(onset['detour_states'])} state(s): {cells}), choosing actions that would "
            "be suboptimal without noise so that a drift cannot carry the agent into a "
            "penalty cell."
            if settings.index(onset) > 0
            else f"Already at drift {onset['drift']:g} the policy takes detours at {cells}."
        )
        if last["detour_states"] and last is not onset:
            sentences.append(
                f"At drift {last['drift']:g}, {len(last['detour_states'])} states deviate "
                f"from the shortest path and the expected number of penalty entries is "
                f"{last['expected_penalty_visits']:.3f} (against "
                f"{max(s['expected_penalty_visits'] for s in settings):.3f} at the worst "
                "level): the agent accepts a much longer walk to stay clear of the hazards."
            )
    return sentences


def hazard_value_loss(
    deterministic: Sequence[float], noisy: Sequence[float], hazards: Sequence[int], top: int = 3
) -> tuple[list[int], bool]:
    """The ``top`` states whose value drops most from the drift-free to the noisy solution
    (terminal/blocked states with value 0 in both are ignored), and whether one of them is
    a hazard or a neighbour of one."""
    size = int(round(math.sqrt(len(deterministic))))
    loss = [
        (d - n, s)
        for s, (d, n) in enumerate(zip(deterministic, noisy, strict=True))
        if not (d == 0 and n == 0)
    ]
    worst = [s for _, s in sorted(loss, key=lambda p: (-p[0], p[1]))[:top]]

    def near(state: int) -> bool:
        r, c = divmod(state, size)
        return any(abs(r - h // size) + abs(c - h % size) <= 1 for h in hazards)

    return worst, any(near(s) for s in worst)


# --------------------------------------------------------------------------- Problem 2
def interval_relation(a: Sequence[float] | None, b: Sequence[float] | None) -> str:
    """'above' if interval ``a`` lies entirely above ``b``, 'below' if entirely below,
    'overlap' otherwise (also when one is missing)."""
    if not a or not b:
        return "overlap"
    if a[0] > b[1]:
        return "above"
    if a[1] < b[0]:
        return "below"
    return "overlap"


def message_effect(difference: float, ci: Sequence[float]) -> tuple[str, str]:
    """Verdict ('helps', 'hurts', 'none') and sentence from real − shuffled success."""
    low, high = ci
    span = f"{100 * difference:+.1f} points (95 % CI [{100 * low:+.1f}, {100 * high:+.1f}])"
    if low > 0:
        return "helps", (
            f"replacing the message by one from another episode lowers success by {span}: "
            "the partner uses the message"
        )
    if high < 0:
        return "hurts", (
            f"success is higher with a message from another episode ({span}): the real "
            "message's content does not help, and a foreign message, uncorrelated with the "
            "situation, seems to act as noise that breaks the deterministic policy's loops"
        )
    return "none", (
        f"real minus shuffled success is {span}, an interval that includes zero: no evidence "
        "that the partner uses the message"
    )


def target_check(name: str, value: float | None, target: float) -> str:
    """'met' or 'missed' wording for a success target of the learning issue."""
    if value is None:
        return f"{name}: no result to compare with the target of {pct(target, 0)}."
    if value >= target - 1e-9:  # 0.55 may arrive as 0.5499999999
        return f"{name}: {pct(value)} meets the target of {pct(target, 0)}."
    gap = 100 * (target - value)
    return f"{name}: {pct(value)} MISSES the target of {pct(target, 0)} by {gap:.1f} points."


def ordering_sentence(means: dict[str, float], cis: dict[str, Sequence[float] | None]) -> str:
    """Whether full > comm > independent holds, and whether the CIs separate the modes."""
    order = sorted(means, key=lambda m: -means[m])
    text = " > ".join(f"{m} ({pct(means[m])})" for m in order)
    separated = [
        f"{a} vs {b}"
        for a, b in zip(order, order[1:], strict=False)
        if interval_relation(cis.get(a), cis.get(b)) == "above"
    ]
    overlapping = [
        f"{a} vs {b}"
        for a, b in zip(order, order[1:], strict=False)
        if interval_relation(cis.get(a), cis.get(b)) != "above"
    ]
    expected = [m for m in ("full", "comm", "independent") if m in means]
    holds = order == expected
    head = f"The ordering by success is {text}. "
    head += (
        "More information gives more success, as expected. "
        if holds
        else "This is NOT the order full > comm > independent that more information suggests. "
    )
    if all(not cis.get(m) for m in order):
        head += "Confidence intervals are not available, so no difference is claimed."
    elif separated:
        head += f"The 95 % CIs separate {join_words(separated)}"
        head += f"; they overlap for {join_words(overlapping)}." if overlapping else "."
    else:
        head += "The 95 % CIs of neighbouring modes overlap, so the ordering is not established."
    return head


def parking_sentence(per_step_success: float, arrival_success: float | None,
                     never_arrives: float, one_on_target: float) -> str:  # fmt: skip
    """Whether the literal per-step reward was hacked by parking one agent on the target."""
    facts = (
        f"Under the literal per-step reward the full-information agents succeed in "
        f"{pct(per_step_success)} of test episodes (ε = 0.05); in {pct(never_arrives)} of "
        f"episodes one agent never reaches the target, and exactly one agent stands on it in "
        f"{pct(one_on_target)} of all steps."
    )
    compared = (
        f" With the arrival reward the same configuration reaches {pct(arrival_success)}."
        if arrival_success is not None
        else ""
    )
    hacked = never_arrives >= 0.5 and (
        arrival_success is None or per_step_success < arrival_success
    )
    if hacked:
        verdict = (
            " The agents learned the loophole: one parks on the target to collect +2 per "
            "step and the other keeps away, since ending the episode would stop the income."
        )
    else:
        verdict = (
            " In this run the parking behaviour is not dominant (fewer than half of the "
            "episodes have an agent that never arrives), so the literal reward was not "
            "clearly hacked here."
        )
    return facts + compared + verdict


def dial_sentence(mode: str, dial: tuple[float, Sequence[float] | None],
                  frozen: tuple[float, Sequence[float] | None]) -> str:  # fmt: skip
    """Compare a mode trained with DIAL messages against the untrained message head."""
    relation = interval_relation(dial[1], frozen[1])
    numbers = f"{pct_ci(*dial)} with DIAL against {pct_ci(*frozen)} with the message head frozen"
    if relation == "above":
        return f"{mode}: {numbers} — training the message with DIAL clearly helps."
    if relation == "below":
        return f"{mode}: {numbers} — the untrained message does better; DIAL hurts here."
    return f"{mode}: {numbers} — the CIs overlap, so no clear effect of training the message."


def generalisation_sentence(trained: float | None, unseen: float, oracle: float) -> str:
    """How the success on unseen maps compares with the training map and the oracle."""
    base = f"on the unseen maps the agents succeed in {pct(unseen)} of episodes on average"
    base += f" (oracle: {pct(oracle)})"
    if trained is None:
        return base + "."
    drop = trained - unseen
    if drop > 0.1:
        return base + (
            f", {100 * drop:.0f} points below the {pct(trained)} on the training map: the "
            "policies are largely specific to the map they were trained on."
        )
    if drop < -0.1:
        return base + f", more than on the training map ({pct(trained)})."
    return base + f", close to the {pct(trained)} on the training map: the strategy transfers."


def action_name(action: int) -> str:
    return ACTION_NAMES[int(action)]
