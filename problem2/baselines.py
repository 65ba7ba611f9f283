"""Reference policies for problem 2 (they run through ``rollout.run_episodes`` like the agents).

* :func:`random_policy`: uniform random actions and messages.
* :func:`oracle_policy`: full information; each agent follows a shortest path to the
  target (breadth-first distances) and the first to arrive waits there.

``python baselines.py`` evaluates both on the default map (seed 641) and map seeds 0–4,
prints a table and writes ``results/evaluation_results/baselines.json``.
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

import numpy as np
from _atomic import write_json_atomic
from grid_maps import ACTION_DELTAS, DEFAULT_MAP_SEED, OBSTACLE, generate_map, target_distances
from multi_agent_env import REWARD_MODES, VectorMultiAgentEnv
from rollout import EVAL_SEED, PolicyFn, evaluate_policy

RESULTS_DIR = Path(__file__).resolve().parent / "results" / "evaluation_results"
MAP_SEEDS = (DEFAULT_MAP_SEED, 0, 1, 2, 3, 4)


def random_policy(seed: int | None = None) -> PolicyFn:
    """Uniform random actions in 0..4 and messages in [0, 1]."""
    rng = np.random.default_rng(seed)

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(obs)
        return rng.integers(len(ACTION_DELTAS), size=(n, 2)), rng.random((n, 2))

    return act


def shortest_path_actions(grid: np.ndarray) -> np.ndarray:
    """Action (H, W) int64 that moves one step closer to the target along a shortest
    path (the lowest-numbered such action); Stay (4) on the target and on obstacles."""
    distances = target_distances(grid).astype(np.float64)
    distances[distances < 0] = np.inf
    padded = np.pad(distances, 1, constant_values=np.inf)
    rows, cols = grid.shape
    after_move = np.stack(
        [padded[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols] for dr, dc in ACTION_DELTAS]
    )
    actions = np.argmin(after_move, axis=0)  # Stay (index 4) wins only where nothing is closer
    actions[grid == OBSTACLE] = len(ACTION_DELTAS) - 1
    return actions


def oracle_policy(grid: np.ndarray) -> PolicyFn:
    """Full-information policy: both agents walk shortest paths; on the target, Stay."""
    table = shortest_path_actions(grid)

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return table[positions[..., 0], positions[..., 1]], np.zeros(positions.shape[:2])

    return act


def evaluate_baselines(
    num_episodes: int = 1000, map_seeds: tuple[int, ...] = MAP_SEEDS, seed: int = EVAL_SEED
) -> dict:
    """Random and oracle policies on each map, under both reward modes (the episodes and
    so success and steps are the same in both; only the return differs)."""
    maps = {}
    for map_seed in map_seeds:
        grid = generate_map((10, 10), map_seed)
        entry: dict = {"grid": grid.tolist()}
        for name, make_policy in (
            ("random", partial(random_policy, seed)),
            ("oracle", partial(oracle_policy, grid)),
        ):
            for mode in REWARD_MODES:
                env = VectorMultiAgentEnv(min(num_episodes, 1000), grid=grid, reward_mode=mode)
                summary = evaluate_policy(env, make_policy(), num_episodes, seed)
                entry.setdefault(name, {k: v for k, v in summary.items() if k != "mean_return"})
                entry[name][f"mean_return_{mode}"] = summary["mean_return"]
        entry["target"] = list(env.target_position)
        maps[str(map_seed)] = entry
    protocol = {
        "grid_size": [10, 10],
        "max_steps": 50,
        "episodes": num_episodes,
        "evaluation_seed": seed,
        "success": "both agents on the target within 50 steps",
    }
    return {"protocol": protocol, "maps": maps}


def format_table(results: dict) -> str:
    header = (
        f"{'map seed':>8} {'target':>8} {'policy':>7} {'success':>8} {'steps':>6} "
        f"{'return (arrival)':>17} {'return (per_step)':>18}"
    )
    lines = [header, "-" * len(header)]
    for map_seed, entry in results["maps"].items():
        for name in ("random", "oracle"):
            row = entry[name]
            steps = row["mean_steps_to_success"]
            lines.append(
                f"{map_seed:>8} {str(tuple(entry['target'])):>8} {name:>7} "
                f"{row['success_rate']:>8.1%} {'-' if steps is None else f'{steps:.2f}':>6} "
                f"{row['mean_return_arrival']:>17.2f} {row['mean_return_per_step']:>18.2f}"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=EVAL_SEED)
    parser.add_argument("--output", type=Path, default=RESULTS_DIR / "baselines.json")
    args = parser.parse_args()
    results = evaluate_baselines(args.episodes, seed=args.seed)
    print(format_table(results))
    write_json_atomic(args.output, results)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
