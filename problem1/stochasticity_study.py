"""How the drift probability changes the optimal policy.

    python stochasticity_study.py [--gamma 0.95] [--epsilon 1e-4] [--results_dir results]

Solves the course gridworld with value iteration for drift probabilities
0, 0.05, 0.1, 0.15, 0.2 and 0.3 per side (the intended move succeeds with
1 - 2 * drift) and writes results/stochasticity_study.json,
results/visualizations/stochasticity_policies.png and
results/visualizations/stochasticity_start_value.png (and .svg).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cli import add_solver_arguments, new_parser

import numpy as np
from environment import GridWorldEnv
from file_io import (
    atomic_save_figure,
    atomic_save_json,
    make_console_safe,
    remove_stale_temporaries,
    shown,
    staged_folder,
)
from matplotlib.figure import Figure
from value_iteration import ValueIteration
from visualize import GridWorldVisualizer

DRIFTS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3)
REFERENCE_DRIFT = 0.1  # the assignment's setting


def solve_drift(drift: float, gamma: float, epsilon: float) -> dict[str, Any]:
    """Value iteration at one drift level plus exact statistics of its greedy policy."""
    env = GridWorldEnv(prob_drift=drift)
    solver = ValueIteration(env, gamma=gamma, epsilon=epsilon)
    values, iterations = solver.solve()
    policy = solver.extract_policy(values)
    model, start = solver.model, solver.model.start_state
    penalty_cells = np.isin(model.next_states, [env.pos_to_state(p) for p in env.penalties])
    # Undiscounted expectations (gamma = 1) under the policy, which reaches the goal surely.
    steps = model.evaluate_policy(policy, 1.0, np.ones_like(model.rewards))
    penalty_visits = model.evaluate_policy(policy, 1.0, penalty_cells.astype(float))
    return {
        "drift": drift,
        "prob_intended": env.prob_intended,
        "iterations": iterations,
        "v_start": float(values[start]),
        "expected_steps": float(steps[start]),
        # a count: clip the -1e-17 round-off of the linear solve
        "expected_penalty_visits": max(0.0, float(penalty_visits[start])),
        "values": values.tolist(),
        "policy": policy.tolist(),
    }


def detour_states(deterministic: dict[str, Any], noisy: dict[str, Any], gamma: float) -> list[int]:
    """Decision states where the ``noisy`` policy picks an action that would be suboptimal
    without drift: the places where noise makes the agent deviate from a shortest path.

    Compared by value, so a different but equally good action is not a detour.
    """
    solver = ValueIteration(GridWorldEnv(prob_drift=deterministic["drift"]), gamma=gamma)
    q_values = solver.model.action_values(np.array(deterministic["values"]), gamma)
    rows = np.arange(solver.n_states)
    chosen = q_values[rows, np.array(noisy["policy"])]
    worse = chosen < q_values.max(axis=1) - 1e-6
    return [int(s) for s in np.flatnonzero(worse & ~solver.model.absorbing)]


def plot_policies(results: list[dict[str, Any]]) -> Figure:
    """One value heatmap per drift level on a shared colour scale, with each cell's value,
    the policy's arrows and the detour states (``detour_states``) framed."""
    visualizer = GridWorldVisualizer()
    decision = ~visualizer.absorbing_cells.reshape(-1)  # goal and obstacles are fixed at 0
    all_values = np.concatenate([np.array(r["values"])[decision] for r in results])
    fig = Figure(figsize=(6.2, 5.2), layout="constrained")
    axes = fig.subplots(2, 3, sharex=True, sharey=True)
    for result, ax in zip(results, axes.flat, strict=True):
        image = visualizer.draw_grid(
            ax,
            np.array(result["values"]),
            np.array(result["policy"]),
            f"drift {result['drift']:.2f} (intended {result['prob_intended']:.1f})\n"
            f"V(start) = {result['v_start']:.2f}",
            vmin=float(all_values.min()),
            vmax=float(all_values.max()),
            compact=True,
            detours=result["detour_states"],
            value_font=10,
        )
    for ax in axes[:, 1:].flat:
        ax.set_ylabel("")
    for ax in axes[0]:
        ax.set_xlabel("")
    colour_bar = fig.colorbar(image, ax=axes, shrink=0.6)
    colour_bar.set_label("V*(s)  (expected discounted return)", fontsize=9)
    colour_bar.ax.tick_params(labelsize=9)
    fig.suptitle("Optimal values and policy as the transitions get noisier", fontsize=11)
    visualizer.add_cell_legend(fig, detours=True)
    return fig


def plot_start_value(results: list[dict[str, Any]]) -> Figure:
    """V(start), expected steps and expected penalty visits against the drift probability."""
    drifts = [r["drift"] for r in results]
    fig = Figure(figsize=(6.5, 2.5), layout="constrained")
    axes = fig.subplots(1, 3)
    panels = (
        ("v_start", "V*(start)", "Value of the start state"),
        ("expected_steps", "expected steps to the goal", "Episode length"),
        ("expected_penalty_visits", "expected penalty entries", "Penalties taken"),
    )
    for ax, (key, label, title) in zip(axes, panels, strict=True):
        ax.plot(drifts, [r[key] for r in results], "o-", markersize=4)
        ax.set_xlabel("drift per side", fontsize=9)
        ax.set_ylabel(label, fontsize=8.5)
        ax.set_title(title, fontsize=10)
        ax.tick_params(labelsize=8)
        ax.grid(True, alpha=0.3)
    return fig


def main(argv: list[str] | None = None) -> dict[str, Any]:
    make_console_safe()
    args = add_solver_arguments(new_parser(__doc__)).parse_args(argv)
    out = Path(args.results_dir)
    remove_stale_temporaries(out)

    results = [solve_drift(drift, args.gamma, args.epsilon) for drift in DRIFTS]
    deterministic = results[0]
    for result in results:
        result["detour_states"] = detour_states(deterministic, result, args.gamma)
    study = {
        "gamma": args.gamma,
        "epsilon": args.epsilon,
        "reference_drift": REFERENCE_DRIFT,
        "settings": results,
    }

    start_value = plot_start_value(results)
    with staged_folder(out) as stage:
        (stage / "visualizations").mkdir()
        atomic_save_json(stage / "stochasticity_study.json", study)
        atomic_save_figure(
            stage / "visualizations" / "stochasticity_policies.png", plot_policies(results)
        )
        for suffix in (".png", ".svg"):
            atomic_save_figure(
                stage / "visualizations" / f"stochasticity_start_value{suffix}", start_value
            )
    print(
        f"{'drift':>6} {'sweeps':>6} {'V(start)':>9} {'E[steps]':>9} {'E[penalties]':>12}"
        f" {'detour states':>14}"
    )
    for r in results:
        print(
            f"{r['drift']:6.2f} {r['iterations']:6d} {r['v_start']:9.3f} {r['expected_steps']:9.2f}"
            f" {r['expected_penalty_visits']:12.3f} {len(r['detour_states']):14d}"
        )
    print(f"results written to {shown(out)}")
    return study


if __name__ == "__main__":
    main()
