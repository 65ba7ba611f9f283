"""The reward study's outputs: the console table and the figure (``reward_study.py``
computes the study dict they read)."""

from __future__ import annotations

from pathlib import Path

from safety import temporary_path_for

CONDITIONS = ("greedy", "epsilon")  # the evaluation conditions, in the order run


def format_table(study: dict) -> str:
    """The exact-DP rows, the shaping check and, with trained batches, one row per reward,
    mode and condition plus the verdict."""
    dp = study["exact_dp"]
    lines = [f"exact DP, map seed {study['protocol']['map_seed']}, {dp['start_pairs']} starts"]
    lines.append(
        f"{'problem':>15} {'reward':>9} {'V*(start)':>9} {'success':>8} {'steps':>6} "
        f"{'ret assign':>10} {'ret arrival':>11} {'one never':>9}"
    )
    for problem in ("finite_horizon", "stationary"):
        for reward, row in dp[problem].items():
            steps = row["mean_steps_to_success"]
            lines.append(
                f"{problem:>15} {reward:>9} {row['optimal_value']['mean']:>9.2f} "
                f"{row['success_rate']:>8.1%} {'-' if steps is None else f'{steps:.1f}':>6} "
                f"{row['return_assignment']:>10.2f} {row['return_arrival']:>11.2f} "
                f"{row['one_never_arrives']:>9.1%}"
            )
    shaped = study["shaping_check"]["shaped_optimum"]
    lines.append(
        f"stationary optimum of the assignment's reward + distance potential shaping: success "
        f"{shaped['success_rate']:.1%}, one never arrives {shaped['one_never_arrives']:.1%}"
    )
    learned = study.get("learned")
    if learned:
        lines.append("learned agents, mean over seeds (success 95 % CI)")
        for reward, modes in learned.items():
            for mode, entry in modes.items():
                for condition in CONDITIONS:
                    row = entry[condition]
                    low, high = row["success_rate"]["ci95"]
                    lines.append(
                        f"{reward:>9} {mode:>11} {condition:>7} success "
                        f"{row['success_rate']['mean']:.1%} [{low:.1%}, {high:.1%}]  "
                        f"ret assign {row['return_assignment']['mean']:7.2f}  "
                        f"ret arrival {row['return_arrival']['mean']:6.2f}  one never "
                        f"{row['one_never_arrives']['mean']:.1%}  turned away "
                        f"{row['turned_away']['mean']:.1%}"
                    )
        verdict = study["verdict"]
        lines.append(
            f"literal reward misspecified (more of its return, less success) in "
            f"{verdict['cases_misspecified']} of {verdict['cases']} mode x condition cases"
        )
    return "\n".join(lines)


REWARD_LABELS = {"per_step": "assignment's reward", "arrival": "arrival reward"}
MODE_MARKERS = {"independent": "o", "comm": "s", "distance": "D", "full": "^"}
DP_OPTIMA = (  # (problem, reward, label, marker)
    ("finite_horizon", "per_step", "DP: assignment's, with clock", "*"),
    ("stationary", "per_step", "DP: assignment's, no clock", "P"),
    ("finite_horizon", "arrival", "DP: arrival reward", "X"),
)


def plot_study(study: dict, path: Path) -> None:
    """Success vs assignment-reward return, one point per trained seed (colour and shape:
    mode; filled: trained on the assignment's reward, hollow: on the arrival reward), one
    panel per condition; the exact-DP optima (DP) in black. Drawn at the width the report prints
    it (4.9 in)."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from train import MODE_COLOURS

    fig = Figure(figsize=(4.9, 4.3), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    modes = sorted(
        {m for modes in study.get("learned", {}).values() for m in modes},
        key=list(MODE_MARKERS).index,
    )
    for axis, condition in zip(axes, CONDITIONS, strict=True):
        for reward, entries in study.get("learned", {}).items():
            for mode, entry in entries.items():
                colour, filled = MODE_COLOURS[mode], reward == "per_step"
                axis.scatter(
                    entry[condition]["return_assignment"]["per_seed"],
                    entry[condition]["success_rate"]["per_seed"],
                    marker=MODE_MARKERS[mode],
                    s=26,
                    linewidths=1.1,
                    edgecolors=colour,
                    facecolors=colour if filled else "none",
                    alpha=0.85,
                )
        for problem, reward, _, marker in DP_OPTIMA:
            row = study["exact_dp"][problem][reward]
            axis.scatter(
                row["return_assignment"],
                row["success_rate"],
                marker=marker,
                s=90,
                facecolors="none",
                edgecolors="black",
            )
        epsilon = study["protocol"]["conditions"][condition]
        axis.set_title("greedy" if condition == "greedy" else f"ε = {epsilon:g}", fontsize=9)
        axis.set_xlabel("mean return under\nthe assignment's reward", fontsize=9)
        axis.tick_params(labelsize=8)
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("success rate (one point per seed)", fontsize=9)
    axes[0].set_ylim(-0.03, 1.05)
    legend = [
        Line2D([], [], ls="", marker=MODE_MARKERS[m], color=MODE_COLOURS[m], label=m) for m in modes
    ]
    legend += [
        Line2D([], [], ls="", marker="o", color="0.3", mfc=fill, label=f"trained on {words}")
        for fill, words in (("0.3", REWARD_LABELS["per_step"]), ("none", REWARD_LABELS["arrival"]))
    ]
    legend += [
        Line2D([], [], ls="", marker=marker, ms=9, mfc="none", mec="black", label=label)
        for _, _, label, marker in DP_OPTIMA
    ]
    fig.legend(handles=legend, loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    with temporary_path_for(path) as temporary:
        fig.savefig(temporary, format="png", dpi=150, metadata={"Software": None})
