"""The reward study's outputs: the console table and the figure (``reward_study.py``
computes the study dict they read)."""

from __future__ import annotations

from pathlib import Path

CONDITIONS = ("greedy", "epsilon")  # the evaluation conditions, in the order run


def format_table(study: dict) -> str:
    """The exact-DP rows, the shaping check and, with trained batches, one row per reward,
    mode and condition plus the verdict."""
    dp = study["exact_dp"]
    lines = [f"exact DP, map seed {study['protocol']['map_seed']}, {dp['start_pairs']} starts"]
    lines.append(f"{'problem':>15} {'reward':>9} {'V*(start)':>9} {'success':>8} {'steps':>6} "
                 f"{'ret assign':>10} {'ret arrival':>11} {'one never':>9}")  # fmt: skip
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


def plot_study(study: dict, path: Path) -> None:
    """Success vs assignment-reward return, one point per trained seed and reward (colour:
    trained reward, marker: mode), one panel per condition; exact-DP optima as stars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    colours = {"per_step": "tab:red", "arrival": "tab:blue"}
    markers = {"independent": "o", "comm": "s", "full": "^"}
    dp = study["exact_dp"]
    optima = [
        ("finite_horizon", "per_step", "DP, assignment, with clock", "*"),
        ("stationary", "per_step", "DP, assignment, no clock", "P"),
        ("finite_horizon", "arrival", "DP, arrival", "X"),
    ]
    legend = [
        Line2D(
            [], [], ls="", marker="o", color=colours["per_step"], label="trained on assignment rew."
        ),
        Line2D(
            [], [], ls="", marker="o", color=colours["arrival"], label="trained on arrival rew."
        ),
    ]
    legend += [
        Line2D([], [], ls="", marker=marker, color="grey", label=mode)
        for mode, marker in markers.items()
    ]
    legend += [
        Line2D([], [], ls="", marker=marker, ms=9, mfc="none", mec="black", label=label)
        for _, _, label, marker in optima
    ]
    with plt.rc_context({"font.size": 9, "legend.fontsize": 8}):
        figure, axes = plt.subplots(1, 2, figsize=(4.9, 3.4), sharey=True, layout="constrained")
        for axis, condition in zip(axes, CONDITIONS, strict=True):
            for reward, modes in study.get("learned", {}).items():
                for mode, entry in modes.items():
                    row = entry[condition]
                    axis.scatter(
                        row["return_assignment"]["per_seed"],
                        row["success_rate"]["per_seed"],
                        c=colours[reward],
                        marker=markers[mode],
                        s=22,
                        alpha=0.75,
                    )
            for problem, reward, _, marker in optima:
                row = dp[problem][reward]
                axis.scatter(
                    row["return_assignment"], row["success_rate"], marker=marker, s=90,
                    facecolors="none", edgecolors="black",
                )  # fmt: skip
            epsilon = study["protocol"]["conditions"][condition]
            axis.set_title("greedy" if condition == "greedy" else f"epsilon = {epsilon}")
            axis.set_xlabel("mean return under\nthe assignment's reward")
            axis.grid(alpha=0.3)
        axes[0].set_ylabel("success rate (one point per seed)")
        axes[0].set_ylim(-0.03, 1.05)
        figure.legend(handles=legend, loc="outside lower center", ncol=2, frameon=False)
        path.parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(path, dpi=150, metadata={"Software": None})
        plt.close(figure)
