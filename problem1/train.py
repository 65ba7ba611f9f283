"""Solve the gridworld with value iteration and Q-iteration, verify, and plot.

    python train.py [--seed 641] [--gamma 0.95] [--epsilon 1e-4] [--max_iter 1000]

Writes ``results/value_function.npz``, ``results/q_function.npz``,
``results/optimal_policy.npz``, ``results/summary.json`` and the figures in
``results/visualizations/``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from environment import GridWorldEnv
from file_io import atomic_save_json, atomic_save_npz
from q_iteration import QIteration
from value_iteration import ValueIteration
from visualize import visualize_results

RESULTS_DIR = Path(__file__).resolve().parent / "results"
Z_99 = 2.5758293035489  # two-sided 99 % quantile of the standard normal


def add_solver_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The flags every Problem 1 script shares: --gamma, --epsilon, --results_dir."""
    parser.add_argument("--gamma", type=float, default=0.95, help="discount factor")
    parser.add_argument("--epsilon", type=float, default=1e-4, help="sup-norm stopping threshold")
    parser.add_argument(
        "--results_dir",
        "--results-dir",
        dest="results_dir",
        type=Path,
        default=RESULTS_DIR,
        help="output folder",
    )
    return parser


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = add_solver_arguments(argparse.ArgumentParser(description=__doc__.split("\n")[0]))
    parser.add_argument("--seed", type=int, default=641, help="seed of the Monte-Carlo check")
    parser.add_argument(
        "--max_iter",
        "--max-iter",
        dest="max_iter",
        type=int,
        default=1000,
        help="maximum number of sweeps",
    )
    parser.add_argument(
        "--mc_episodes",
        "--mc-episodes",
        dest="mc_episodes",
        type=int,
        default=10_000,
        help="episodes of the Monte-Carlo check of V(start)",
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
    args = parse_args(argv)
    out = Path(args.results_dir)
    out.mkdir(parents=True, exist_ok=True)
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
        iterations: int, seconds: float, residual: float, history: list[float], start_value: float
    ) -> dict[str, Any]:
        return {
            "iterations": iterations,
            "converged": history[-1] < args.epsilon,
            "wall_time_s": seconds,
            "seconds_per_sweep": seconds / iterations,
            "final_change": history[-1],
            "bellman_residual": residual,
            "v_start": start_value,
        }

    summary = {
        "gamma": args.gamma,
        "epsilon": args.epsilon,
        "seed": args.seed,
        "start_state": start,
        "v_start": float(values[start]),
        "value_iteration": solver_summary(
            vi_iterations, vi_seconds, vi_residual, vi.history, float(values[start])
        ),
        "q_iteration": solver_summary(
            qi_iterations,
            qi_seconds,
            qi_residual,
            qi.history,
            float(qi.extract_values(q_values)[start]),
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

    atomic_save_npz(
        out / "value_function.npz",
        values=values,
        iterations=vi_iterations,
        history=np.array(vi.history),
        gamma=args.gamma,
        epsilon=args.epsilon,
    )
    atomic_save_npz(
        out / "q_function.npz",
        q_values=q_values,
        iterations=qi_iterations,
        history=np.array(qi.history),
        gamma=args.gamma,
        epsilon=args.epsilon,
    )
    atomic_save_npz(
        out / "optimal_policy.npz", policy=vi_policy, vi_policy=vi_policy, qi_policy=qi_policy
    )
    atomic_save_json(out / "summary.json", summary)

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
    visualize_results(out)
    print(f"results written to {out}")
    return summary


if __name__ == "__main__":
    main()
