"""The one episode loop of Problem 2, and the evaluation protocol's constants.

Every evaluation (the trainer's periodic validation, the evaluator's test episodes, the
baselines) runs a policy through :func:`run_episodes` on a vectorised environment, many
episodes at once, with fixed start cells drawn from a seed.

A policy is a plain function ``(observations (N, 2, obs_dim), positions (N, 2, 2)) ->
(actions (N, 2) ints in 0..4, messages (N, 2) in [0, 1])``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from multi_agent_env import VectorMultiAgentEnv

PolicyFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

EVAL_EPSILON = 0.05  # results are reported greedy (epsilon 0) and at this exploration rate
EVAL_SEED = 7_000_000  # start cells of the test episodes (evaluator, baselines)
VALIDATION_SEED = 6_000_000  # other start cells, for checkpoint and seed selection in training


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
    start_positions: np.ndarray | None = None,
) -> EpisodeResults:
    """Run ``num_episodes`` episodes of ``policy_fn`` in rounds of ``env.n_envs``.

    Each round resets every copy together, so at loop step t every unfinished episode is
    at its step t (a policy wrapper may rely on this, e.g. to swap messages between
    episodes). Copies that finish are ignored for the rest of the round. The first round
    resets with ``seed``, later rounds continue its stream: results are reproducible.
    Success means both agents on the target within ``env.max_steps`` steps.
    ``start_positions`` (n_envs, 2, 2) places the agents of the first round by hand
    (instead of drawing from ``seed``).
    """
    if not env.auto_reset:
        raise ValueError("run_episodes needs an environment built with auto_reset=True")
    if num_episodes < 1:
        raise ValueError(f"num_episodes must be positive, got {num_episodes}")
    rounds = [
        _run_round(
            env, policy_fn, seed if i == 0 else None, record, start_positions if i == 0 else None
        )
        for i in range(math.ceil(num_episodes / env.n_envs))
    ]
    joined = {key: np.concatenate([r[key] for r in rounds])[:num_episodes] for key in rounds[0]}
    outcomes = {key: joined.pop(key) for key in ("returns", "successes", "lengths")}
    return EpisodeResults(**outcomes, trajectories=joined if record else None)


def _run_round(
    env: VectorMultiAgentEnv,
    policy_fn: PolicyFn,
    seed: int | None,
    record: bool,
    start_positions: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    n, horizon = env.n_envs, env.max_steps
    obs = env.reset(seed=seed, positions=start_positions)
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


def split_blocks(results: EpisodeResults, blocks: int) -> list[EpisodeResults]:
    """Split ``results`` of ``blocks`` equal consecutive blocks of episodes into one
    ``EpisodeResults`` per block."""

    def part(array: np.ndarray) -> list[np.ndarray]:
        return np.split(array, blocks)

    fields = [part(results.returns), part(results.successes), part(results.lengths)]
    trajectories = results.trajectories
    split = {k: part(v) for k, v in trajectories.items()} if trajectories is not None else None
    return [
        EpisodeResults(
            fields[0][k],
            fields[1][k],
            fields[2][k],
            {key: v[k] for key, v in split.items()} if split is not None else None,
        )  # fmt: skip
        for k in range(blocks)
    ]


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


SELECT_BY = ("steps", "success", "return")  # the rules of select_best (--select_by)
SUCCESS_TOLERANCE = 0.01  # "steps": success rates this close to the best count as equal


def select_best(candidates: Sequence[tuple[dict, dict]], select_by: str) -> int:
    """Index of the best candidate (checkpoint or seed), each a pair of summaries (greedy,
    epsilon = 0.05) on the same validation episodes; of equals, the first.

    ``success`` / ``return``: the highest mean of the two success rates / returns.
    ``steps``: among the candidates whose mean success rate is within ``SUCCESS_TOLERANCE``
    of the best, the one with the fewest mean steps to success."""

    def mean(key: str, pair: tuple[dict, dict]) -> float:
        values = [math.inf if s[key] is None else s[key] for s in pair]
        return (values[0] + values[1]) / 2

    indices = range(len(candidates))
    if select_by == "steps":
        success = [mean("success_rate", pair) for pair in candidates]
        threshold = max(success) - SUCCESS_TOLERANCE - 1e-9  # 1e-9: rates are k / episodes
        eligible = [i for i in indices if success[i] >= threshold]
        return min(eligible, key=lambda i: (mean("mean_steps_to_success", candidates[i]), i))
    if select_by not in SELECT_BY:
        raise ValueError(f"select_by must be one of {SELECT_BY}, got {select_by!r}")
    key = "success_rate" if select_by == "success" else "mean_return"
    return max(indices, key=lambda i: (mean(key, candidates[i]), -i))


def evaluate_policy(
    env: VectorMultiAgentEnv,
    policy_fn: PolicyFn,
    num_episodes: int = 1000,
    seed: int | None = EVAL_SEED,
) -> dict[str, float | int | None]:
    """:func:`run_episodes` then :func:`summarize`."""
    return summarize(run_episodes(env, policy_fn, num_episodes, seed))
