"""The one episode loop of Problem 2 (every evaluation runs a policy through
:func:`run_episodes`, many episodes at once, start cells from a seed), the evaluation
protocol's constants, and the n-step transitions that learning collects.

A policy is a plain function ``(observations (N, 2, obs_dim), positions (N, 2, 2)) ->
(actions (N, 2) ints in 0..4, messages (N, 2) in [0, 1])``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from vector_env import VectorMultiAgentEnv, positive_int, team_rewards

PolicyFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

EVAL_EPSILON = 0.05  # results are reported greedy (epsilon 0) and at this exploration rate
EVAL_SEED = 7_000_000  # start cells of the test episodes (evaluator, baselines)
VALIDATION_SEED = 6_000_000  # other start cells, for checkpoint and seed selection in training


@dataclass
class EpisodeResults:
    """Per-episode outcomes (E,): ``returns`` under the environment's reward, and
    ``table_returns`` under the assignment's table (+10 / +2 / −0.1) whatever that reward;
    ``trajectories`` if recorded (``analysis.episodes``)."""

    returns: np.ndarray
    successes: np.ndarray
    lengths: np.ndarray
    trajectories: dict[str, np.ndarray] | None = None
    table_returns: np.ndarray | None = None


def run_episodes(
    env: VectorMultiAgentEnv,
    policy_fn: PolicyFn,
    num_episodes: int,
    seed: int | None = None,
    start_positions: np.ndarray | None = None,
) -> EpisodeResults:
    """Run ``num_episodes`` episodes of ``policy_fn`` in rounds of ``env.n_envs``.

    Each round resets every copy together, so at loop step t every unfinished episode is
    at its step t (a policy wrapper may rely on this, e.g. to swap messages between
    episodes). Copies that finish are ignored for the rest of the round. The first round
    resets with ``seed``, later rounds continue its stream: results are reproducible.
    Success means both agents on the target within ``env.max_steps`` steps.
    ``start_positions`` (n_envs, 2, 2) places the first round's agents by hand instead.
    """
    if not env.auto_reset:
        raise ValueError("run_episodes needs an environment built with auto_reset=True")
    if num_episodes < 1:
        raise ValueError(f"num_episodes must be positive, got {num_episodes}")
    n = env.n_envs
    rounds = []
    for i in range(math.ceil(num_episodes / n)):
        obs = env.reset(seed=seed, positions=start_positions) if i == 0 else env.reset()
        active = np.ones(n, dtype=bool)
        result = {
            "returns": np.zeros(n),
            "successes": np.zeros(n, dtype=bool),
            "lengths": np.zeros(n, dtype=np.int64),
            "table_returns": np.zeros(n),
        }
        for _ in range(env.max_steps):
            actions, messages = policy_fn(obs, env.positions)
            obs, rewards, terminated, truncated, info = env.step(actions, messages)
            result["returns"] += np.where(active, rewards, 0.0)
            table = team_rewards(info["on_target"], info["on_target"], "per_step")
            result["table_returns"] += np.where(active, table, 0.0)
            finished = active & (terminated | truncated)
            result["successes"][finished] = terminated[finished]
            result["lengths"][finished] = info["steps"][finished]
            active &= ~finished
            if not active.any():
                break
        rounds.append(result)
    joined = {key: np.concatenate([r[key] for r in rounds])[:num_episodes] for key in rounds[0]}
    return EpisodeResults(**joined)


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


def validation_summary(results: EpisodeResults) -> dict[str, float | int | None]:
    """:func:`summarize` with the mean return under the assignment's table on the same
    episodes (``mean_table_return``): what training logs at each periodic evaluation."""
    return summarize(results) | {"mean_table_return": float(results.table_returns.mean())}


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


# ------------------------------------------------ collecting experience (learning)
class NStepWindow:
    """Turns the steps of N parallel episodes into n-step transitions.

    The transition that starts at step t carries the discounted reward R = r_t + γ r_{t+1}
    + ... + γ^(k-1) r_{t+k-1}, the observation s_{t+k} it bootstraps from (``next_state_*``),
    for n > 1 the observation s_{t+k-1} before it (``last_state_*``, whose sender's message
    s_{t+k} holds) and the discount γ^k, 0 if the episode terminated within those k steps;
    k is n, or fewer where the episode ends (terminal or cut off) first. To the fields the
    caller gives at the start the window adds ``reward``, ``next_state_A``/``_B``, ``done``
    and ``discount``. Each field's ring has n rows of N slots: the transition starting at
    step s in copy c is slot (s % n) * N + c.
    """

    def __init__(self, n_step: int, gamma: float, n_envs: int) -> None:
        self.n_step, self.gamma, self.n_envs = positive_int(n_step, "n_step"), float(gamma), n_envs
        self.discounts = np.array([self.gamma**k for k in range(n_step + 1)])  # γ^k
        self.started: dict[str, np.ndarray] = {}  # each start field's ring (n * N, ...)
        self.returns = np.zeros((n_step, n_envs))  # discounted rewards so far (float64)
        self.steps_added = 0
        self.in_episode = np.zeros(n_envs, np.int64)  # window steps of each running episode

    def add(
        self,
        start: dict[str, np.ndarray],
        reward: np.ndarray,
        next_obs: np.ndarray,
        obs: np.ndarray,
        terminated: np.ndarray,
        finished: np.ndarray,
    ) -> dict[str, np.ndarray]:
        """One step of the N episodes.

        Args:
            start: the fields of the transitions starting now, each (N, ...).
            reward: (N,) this step's rewards.
            next_obs, obs: (N, 2, D) the observations after and before the step.
            terminated, finished: (N,) bool; finished = terminated or cut off.

        Returns the K transitions that are complete, oldest start first (by copy within
        one start step), each field (K, ...); K may be 0."""
        n, copies, row = self.n_step, self.n_envs, self.steps_added % self.n_step
        if not self.started:  # the first add: one ring per field
            self.started = {
                name: np.zeros((n * copies, *values.shape[1:]), values.dtype)
                for name, values in start.items()
            }
        held = min(self.steps_added, n - 1)  # earlier steps still in the window
        older = (row - np.arange(1, held + 1)) % n  # their rows, newest first (age 1, 2, ...)
        self.returns[older] += self.discounts[1 : held + 1, None] * reward
        self.returns[row] = reward
        for name, values in start.items():
            self.started[name][row * copies : (row + 1) * copies] = values
        self.steps_added += 1
        self.in_episode = np.minimum(self.in_episode + 1, n)
        # Steps since each transition began (oldest first), and which are due now.
        lags = np.arange(held, -1, -1)[:, None]
        due = (lags < self.in_episode) & (finished | (lags == n - 1))
        self.in_episode[finished] = 0
        lag, env = np.nonzero(due)  # in order: oldest start first, then by copy
        lag = held - lag
        slots = (row - lag) % n * copies + env
        done = terminated[env]
        complete = {name: ring[slots] for name, ring in self.started.items()}
        complete |= {
            "reward": self.returns.reshape(-1)[slots].astype(np.float32),
            "next_state_A": next_obs[env, 0],
            "next_state_B": next_obs[env, 1],
            "done": done.astype(np.float32),
            "discount": np.where(done, 0.0, self.discounts[lag + 1]).astype(np.float32),
            "last_state_A": obs[env, 0],
            "last_state_B": obs[env, 1],
        }
        return complete


@dataclass
class Rollout:
    """N environment copies being played, and what the learner tracks for each."""

    env: VectorMultiAgentEnv
    obs: np.ndarray  # (N, 2, D) current observations of A and B
    prev_obs: np.ndarray  # (N, 2, D) observations one step earlier (zeros at an episode start)
    has_prev: np.ndarray  # (N,) float32, 1.0 where prev_obs is real
    returns: np.ndarray  # (N,) return of the running episodes
    window: NStepWindow  # the steps whose n-step transitions are not complete yet

    @classmethod
    def start(cls, env: VectorMultiAgentEnv, n_step: int = 1, gamma: float = 0.99) -> Rollout:
        obs = env.reset()
        n = env.n_envs
        zeros = np.zeros(n, np.float32)
        return cls(env, obs, np.zeros_like(obs), zeros, np.zeros(n), NStepWindow(n_step, gamma, n))

    def advance(
        self, next_obs: np.ndarray, rewards: np.ndarray, finished: np.ndarray
    ) -> np.ndarray:
        """Move on to ``next_obs``; return the returns of the episodes that ``finished``."""
        self.returns += rewards
        finished_returns = self.returns[finished].copy()
        self.returns[finished] = 0.0
        self.prev_obs = np.where(finished[:, None, None], np.float32(0), self.obs)
        self.has_prev = (~finished).astype(np.float32)
        self.obs = next_obs
        return finished_returns
