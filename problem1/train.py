"""Solve the gridworld with value iteration and Q-iteration, verify, and plot.

    python train.py [--seed 641] [--gamma 0.95] [--epsilon 1e-4] [--max_iter 1000]

Writes results/value_function.npz, q_function.npz, optimal_policy.npz, summary.json
(everything but wall time; identical on every rerun), timing.json (wall time) and the
figures in results/visualizations/. The set is written into a hidden staging folder and
moved into place at the end, so an interrupted run leaves the previous results intact.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

from cli import add_solver_arguments, int_at_least, new_parser

import numpy as np
from environment import GridWorldEnv
from file_io import (
    atomic_save_json,
    atomic_save_npz,
    make_console_safe,
    remove_stale_temporaries,
    settings_id,
    shown,
    staged_folder,
)
from q_iteration import QIteration
from value_iteration import ValueIteration
from visualize import visualize_results

Z_99 = 2.5758293035489  # two-sided 99 % quantile of the standard normal


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = add_solver_arguments(new_parser(__doc__))
    parser.add_argument(
        "--seed", type=int_at_least(0), default=641, help="seed of the Monte-Carlo check"
    )
    parser.add_argument(
        "--max_iter",
        "--max-iter",
        dest="max_iter",
        type=int_at_least(1),
        default=1000,
        help="maximum number of sweeps",
    )
    parser.add_argument(
        "--mc_episodes",
        "--mc-episodes",
        dest="mc_episodes",
        type=int_at_least(2),
        default=10_000,
        help="episodes of the Monte-Carlo check of V(start) (>= 2)",
    )
    return parser.parse_args(argv)


def timed_solve(
    solver: ValueIteration | QIteration, max_iter: int
) -> tuple[np.ndarray, int, float]:
    """``solve`` plus its wall time in seconds."""
    start = time.perf_counter()
    solution, iterations = solver.solve(max_iter)
    return solution, iterations, time.perf_counter() - start


def policies_agree(
    q_star: np.ndarray,
    policy_a: np.ndarray,
    policy_b: np.ndarray,
    absorbing: np.ndarray,
    tolerance: float,
) -> bool:
    """True when, in every decision state, both policies pick an action whose value is
    within ``tolerance`` of the best one (so two equally good actions count as agreement)."""
    rows = np.arange(len(q_star))
    best = q_star.max(axis=1)
    near_optimal = [q_star[rows, p] >= best - tolerance for p in (policy_a, policy_b)]
    return bool(np.all((near_optimal[0] & near_optimal[1]) | absorbing))


def monte_carlo_return(
    env: GridWorldEnv, policy: np.ndarray, gamma: float, episodes: int
) -> dict[str, Any]:
    """Discounted return from the start over ``episodes`` runs of ``policy`` with ``env.step``.

    Episodes stop at the goal or at the 50-step limit, so this estimates the
    truncated return; the truncated tail is negligible for a goal-reaching policy.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 2:
        raise ValueError(
            f"episodes must be an integer >= 2 (for a confidence interval), got {episodes!r}"
        )
    returns = np.empty(episodes)
    for episode in range(episodes):
        state, done, discount, total = env.reset(), False, 1.0, 0.0
        while not done:
            state, reward, done, _ = env.step(int(policy[state]))
            total += discount * reward
            discount *= gamma
        returns[episode] = total
    mean = float(returns.mean())
    half_width = Z_99 * float(returns.std(ddof=1)) / math.sqrt(episodes)
    return {
        "episodes": episodes,
        "mean_return": mean,
        "ci99": [mean - half_width, mean + half_width],
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    make_console_safe()
    args = parse_args(argv)
    out = Path(args.results_dir)
    remove_stale_temporaries(out)
    settings = {
        "gamma": args.gamma,
        "epsilon": args.epsilon,
        "max_iter": args.max_iter,
        "seed": args.seed,
        "mc_episodes": args.mc_episodes,
    }
    run_id = settings_id(settings)
    env = GridWorldEnv(seed=args.seed)

    vi = ValueIteration(env, gamma=args.gamma, epsilon=args.epsilon)
    values, vi_iterations, vi_seconds = timed_solve(vi, args.max_iter)
    qi = QIteration(env, gamma=args.gamma, epsilon=args.epsilon)
    q_values, qi_iterations, qi_seconds = timed_solve(qi, args.max_iter)

    vi_policy, qi_policy = vi.extract_policy(values), qi.extract_policy(q_values)
    vi_residual, qi_residual = vi.compute_bellman_error(values), qi.compute_bellman_error(q_values)
    residual_bound = vi_residual / (1.0 - args.gamma)  # ||V_pi - V|| <= ||TV - V|| / (1 - gamma)
    q_star = vi.model.action_values(values, args.gamma)
    agree = policies_agree(q_star, vi_policy, qi_policy, vi.model.absorbing, 2 * residual_bound)

    policy_values = vi.model.evaluate_policy(vi_policy, args.gamma)
    start = vi.model.start_state
    monte_carlo = monte_carlo_return(env, vi_policy, args.gamma, args.mc_episodes)
    lo, hi = monte_carlo["ci99"]
    monte_carlo["contains_v_start"] = bool(lo <= values[start] <= hi)

    def solver_summary(
        iterations: int, residual: float, history: list[float], start_value: float
    ) -> dict[str, Any]:
        return {
            "iterations": iterations,
            "converged": history[-1] < args.epsilon,
            "final_change": history[-1],
            "bellman_residual": residual,
            "v_start": start_value,
        }

    summary = {
        **settings,
        "run_id": run_id,
        "start_state": start,
        "v_start": float(values[start]),
        "value_iteration": solver_summary(
            vi_iterations, vi_residual, vi.history, float(values[start])
        ),
        "q_iteration": solver_summary(
            qi_iterations, qi_residual, qi.history, float(qi.extract_values(q_values)[start])
        ),
        "max_value_difference_vi_qi": float(np.max(np.abs(values - qi.extract_values(q_values)))),
        "policies_agree": agree,
        "policies_identical": bool(np.array_equal(vi_policy, qi_policy)),
        "verification": {
            "policy_evaluation_max_error": float(np.max(np.abs(policy_values - values))),
            "residual_bound": residual_bound,
            "within_bound": bool(np.max(np.abs(policy_values - values)) <= residual_bound),
            "monte_carlo": monte_carlo,
        },
    }
    timing = {
        "run_id": run_id,
        "value_iteration": {
            "wall_time_s": vi_seconds,
            "seconds_per_sweep": vi_seconds / vi_iterations,
        },
        "q_iteration": {
            "wall_time_s": qi_seconds,
            "seconds_per_sweep": qi_seconds / qi_iterations,
        },
    }

    with staged_folder(out) as stage:
        atomic_save_npz(
            stage / "value_function.npz",
            values=values,
            iterations=vi_iterations,
            history=np.array(vi.history),
            gamma=args.gamma,
            epsilon=args.epsilon,
            run_id=run_id,
        )
        atomic_save_npz(
            stage / "q_function.npz",
            q_values=q_values,
            iterations=qi_iterations,
            history=np.array(qi.history),
            gamma=args.gamma,
            epsilon=args.epsilon,
            run_id=run_id,
        )
        atomic_save_npz(
            stage / "optimal_policy.npz",
            policy=vi_policy,
            vi_policy=vi_policy,
            qi_policy=qi_policy,
            run_id=run_id,
        )
        atomic_save_json(stage / "summary.json", summary)
        atomic_save_json(stage / "timing.json", timing)
        visualize_results(stage)

    print(
        f"value iteration: {vi_iterations} sweeps, {vi_seconds * 1e3:.1f} ms, "
        f"residual {vi_residual:.2e}"
    )
    print(
        f"Q-iteration:     {qi_iterations} sweeps, {qi_seconds * 1e3:.1f} ms, "
        f"residual {qi_residual:.2e}"
    )
    print(
        f"V(start) = {values[start]:.4f}; Monte-Carlo {monte_carlo['mean_return']:.4f} "
        f"(99 % CI {lo:.4f} .. {hi:.4f}); policies agree: {agree}"
    )
    env.render(values)
    print(f"results written to {shown(out)}")
    return summary


if __name__ == "__main__":
    main()
