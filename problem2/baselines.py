"""Reference policies for problem 2 and the episode loop every evaluation shares.

* :func:`run_episodes` / :func:`evaluate_policy` run any policy on a vectorised
  environment, many episodes at once; trained networks are evaluated with the same code.
* :func:`random_policy`: uniform random actions and messages.
* :func:`oracle_policy`: full information; each agent follows a shortest path to the
  target (breadth-first distances) and the first to arrive waits there.

``python baselines.py`` evaluates both on the default map (seed 641) and map seeds 0–4,
prints a table and writes ``results/evaluation_results/baselines.json``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from _atomic import write_json_atomic
from grid_maps import ACTION_DELTAS, DEFAULT_MAP_SEED, OBSTACLE, generate_map, target_distances
from multi_agent_env import REWARD_MODES, VectorMultiAgentEnv

# (observations (N, 2, obs_dim), positions (N, 2, 2)) -> (actions (N, 2), messages (N, 2))
PolicyFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

RESULTS_DIR = Path(__file__).resolve().parent / "results" / "evaluation_results"
MAP_SEEDS = (DEFAULT_MAP_SEED, 0, 1, 2, 3, 4)
EVALUATION_SEED = 2024


@dataclass
class EpisodeResults:
    """Per-episode outcomes (E,) and, if recorded, trajectories padded to max_steps T.

    ``trajectories``: positions (E, T + 1, 2, 2) and observations (E, T + 1, 2, obs_dim)
    before each step and after the last (held after the episode ends); actions (E, T, 2)
    (-1 after the end), messages sent (E, T, 2) (NaN after), rewards (E, T) (0 after).
    """

    returns: np.ndarray
    successes: np.ndarray
    lengths: np.ndarray
    trajectories: dict[str, np.ndarray] | None = None


def run_episodes(
    env: VectorMultiAgentEnv,
    policy_fn: PolicyFn,
    num_episodes: int,
    seed: int | None = None,
    record: bool = False,
) -> EpisodeResults:
    """Run ``num_episodes`` episodes of ``policy_fn`` in rounds of ``env.n_envs``.

    Each round resets every copy together, so at loop step t every unfinished episode is
    at its step t (a policy wrapper may rely on this, e.g. to swap messages between
    episodes). Copies that finish are ignored for the rest of the round. The first round
    resets with ``seed``, later rounds continue its stream: results are reproducible.
    Success means both agents on the target within ``env.max_steps`` steps.
    """
    if not env.auto_reset:
        raise ValueError("run_episodes needs an environment built with auto_reset=True")
    if num_episodes < 1:
        raise ValueError(f"num_episodes must be positive, got {num_episodes}")
    rounds = [
        _run_round(env, policy_fn, seed if i == 0 else None, record)
        for i in range(math.ceil(num_episodes / env.n_envs))
    ]
    joined = {key: np.concatenate([r[key] for r in rounds])[:num_episodes] for key in rounds[0]}
    outcomes = {key: joined.pop(key) for key in ("returns", "successes", "lengths")}
    return EpisodeResults(**outcomes, trajectories=joined if record else None)


def _run_round(
    env: VectorMultiAgentEnv, policy_fn: PolicyFn, seed: int | None, record: bool
) -> dict[str, np.ndarray]:
    n, horizon = env.n_envs, env.max_steps
    obs = env.reset(seed=seed)
    active = np.ones(n, dtype=bool)
    result = {
        "returns": np.zeros(n),
        "successes": np.zeros(n, dtype=bool),
        "lengths": np.zeros(n, dtype=np.int64),
    }
    if record:
        result |= {
            "positions": np.zeros((n, horizon + 1, 2, 2), dtype=np.int64),
            "observations": np.zeros((n, horizon + 1, 2, env.obs_dim), dtype=np.float32),
            "actions": np.full((n, horizon, 2), -1, dtype=np.int64),
            "messages": np.full((n, horizon, 2), np.nan, dtype=np.float32),
            "rewards": np.zeros((n, horizon), dtype=np.float32),
        }
        result["positions"][:, 0], result["observations"][:, 0] = env.positions, obs
    for t in range(horizon):
        actions, messages = policy_fn(obs, env.positions)
        obs, rewards, terminated, truncated, info = env.step(actions, messages)
        result["returns"] += np.where(active, rewards, 0.0)
        if record:
            _record_step(result, t, active, actions, messages, rewards, info)
        finished = active & (terminated | truncated)
        result["successes"][finished] = terminated[finished]
        result["lengths"][finished] = info["steps"][finished]
        active &= ~finished
        if not active.any():
            break
    return result


def _record_step(
    log: dict[str, np.ndarray],
    t: int,
    active: np.ndarray,
    actions: np.ndarray,
    messages: np.ndarray,
    rewards: np.ndarray,
    info: dict,
) -> None:
    rows = np.flatnonzero(active)
    log["actions"][rows, t] = actions[rows]
    log["messages"][rows, t] = messages[rows]
    log["rewards"][rows, t] = rewards[rows]
    for key, new in (("positions", info["positions"]), ("observations", info["final_obs"])):
        log[key][:, t + 1] = log[key][:, t]  # hold the last state after the episode ends
        log[key][rows, t + 1] = new[rows]


def summarize(results: EpisodeResults) -> dict[str, float | int | None]:
    """Success rate, mean steps of the successful episodes (None if none), mean return."""
    successes = results.successes
    return {
        "episodes": len(successes),
        "success_rate": float(successes.mean()),
        "mean_steps_to_success": float(results.lengths[successes].mean())
        if successes.any()
        else None,
        "mean_return": float(results.returns.mean()),
    }


def evaluate_policy(
    env: VectorMultiAgentEnv,
    policy_fn: PolicyFn,
    num_episodes: int = 1000,
    seed: int | None = EVALUATION_SEED,
) -> dict[str, float | int | None]:
    """:func:`run_episodes` then :func:`summarize`."""
    return summarize(run_episodes(env, policy_fn, num_episodes, seed))


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
    num_episodes: int = 1000, map_seeds: tuple[int, ...] = MAP_SEEDS, seed: int = EVALUATION_SEED
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
    parser.add_argument("--seed", type=int, default=EVALUATION_SEED)
    parser.add_argument("--output", type=Path, default=RESULTS_DIR / "baselines.json")
    args = parser.parse_args()
    results = evaluate_baselines(args.episodes, seed=args.seed)
    print(format_table(results))
    write_json_atomic(args.output, results)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
