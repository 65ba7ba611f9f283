"""Running policies for Problem 2's evaluation: the greedy policy of two models and the
shortest-path oracle, exploration with common random numbers, fixed start cells, recorded
episodes, per-episode summaries.

Every policy here has the ``rollout.PolicyFn`` signature, so random, oracle and trained
policies all run through :func:`rollout.run_episodes`.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from rollout import EVAL_SEED, EpisodeResults, PolicyFn, run_episodes, summarize
from vector_env import ACTION_DELTAS, NUM_ACTIONS, OBSTACLE, TARGET, VectorMultiAgentEnv

from analysis.failures import failure_shares
from analysis.runs import check_policy_outputs

MAX_BATCH = 20_000  # copies stepped together (test episodes x blocks); more run in groups
SUCCESS = "both agents on the target on the same step within max_steps"  # in every file


@dataclass(frozen=True)
class EvaluationSetting:
    """The map and episode rules an evaluation runs on."""

    grid: np.ndarray  # (H, W) int: 0 free, 1 obstacle, 2 target
    reward_mode: str = "per_step"  # the assignment's reward, as reported
    max_steps: int = 50
    obs_window: int = 3

    def make_env(self, copies: int) -> VectorMultiAgentEnv:
        """A vectorised environment of ``copies`` copies of this map and rules."""
        return VectorMultiAgentEnv(
            copies,
            grid=self.grid,
            obs_window=self.obs_window,
            max_steps=self.max_steps,
            reward_mode=self.reward_mode,
        )

    @property
    def target(self) -> tuple[int, int]:
        row, col = np.argwhere(np.asarray(self.grid) == 2)[0]
        return int(row), int(col)


class RecordingEnv:
    """A vectorised environment seen through :func:`rollout.run_episodes` that records
    every round it plays (one round per ``reset``), each a dict of trajectories padded to
    max_steps T: positions (N, T + 1, 2, 2) and observations (N, T + 1, 2, obs_dim) before
    each step and after the last (held after the episode ends); actions (N, T, 2) (-1
    after the end), messages sent (N, T, 2) (NaN after), rewards (N, T) (0 after)."""

    def __init__(self, env: VectorMultiAgentEnv) -> None:
        self.env, self.rounds = env, []
        self.n_envs, self.max_steps, self.auto_reset = env.n_envs, env.max_steps, env.auto_reset

    @property
    def positions(self) -> np.ndarray:
        return self.env.positions

    def reset(self, seed: int | None = None, positions: np.ndarray | None = None) -> np.ndarray:
        obs = self.env.reset(seed=seed, positions=positions)
        n, horizon = self.n_envs, self.max_steps
        self.t, self.active = 0, np.ones(n, dtype=bool)
        self.rounds.append(
            {
                "positions": np.zeros((n, horizon + 1, 2, 2), dtype=np.int64),
                "observations": np.zeros((n, horizon + 1, 2, self.env.obs_dim), dtype=np.float32),
                "actions": np.full((n, horizon, 2), -1, dtype=np.int64),
                "messages": np.full((n, horizon, 2), np.nan, dtype=np.float32),
                "rewards": np.zeros((n, horizon), dtype=np.float32),
            }
        )
        log = self.rounds[-1]
        log["positions"][:, 0], log["observations"][:, 0] = self.env.positions, obs
        return obs

    def step(self, actions: np.ndarray, messages: np.ndarray) -> tuple:
        """``env.step``, recording the step of every copy whose episode is still running."""
        result = self.env.step(actions, messages)
        _, rewards, terminated, truncated, info = result
        log, t, rows = self.rounds[-1], self.t, np.flatnonzero(self.active)
        log["actions"][rows, t] = actions[rows]
        log["messages"][rows, t] = messages[rows]
        log["rewards"][rows, t] = rewards[rows]
        for key, new in (("positions", info["positions"]), ("observations", info["final_obs"])):
            log[key][:, t + 1] = log[key][:, t]  # hold the last state after the episode ends
            log[key][rows, t + 1] = new[rows]
        self.active &= ~(terminated | truncated)
        self.t += 1
        return result


def recorded_episodes(
    env: VectorMultiAgentEnv,
    policy_fn: PolicyFn,
    num_episodes: int,
    seed: int | None = None,
    start_positions: np.ndarray | None = None,
) -> EpisodeResults:
    """:func:`rollout.run_episodes` with the trajectories of :class:`RecordingEnv` (E, ...)."""
    recorder = RecordingEnv(env)
    results = run_episodes(recorder, policy_fn, num_episodes, seed, start_positions)
    rounds = recorder.rounds
    joined = {key: np.concatenate([r[key] for r in rounds])[:num_episodes] for key in rounds[0]}
    return dataclasses.replace(results, trajectories=joined)


def target_distances(grid: np.ndarray) -> np.ndarray:
    """Shortest-path length (H, W) int64 from every cell to the target by breadth-first
    search over 4-neighbour moves; -1 for obstacles and cells that cannot reach it."""
    rows, cols = grid.shape
    distances = np.full((rows, cols), -1, dtype=np.int64)
    start = tuple(int(i) for i in np.argwhere(grid == TARGET)[0])
    distances[start] = 0
    frontier = deque([start])
    while frontier:
        row, col = frontier.popleft()
        for d_row, d_col in ACTION_DELTAS[:4]:
            r, c = row + d_row, col + d_col
            if 0 <= r < rows and 0 <= c < cols and grid[r, c] != OBSTACLE and distances[r, c] < 0:
                distances[r, c] = distances[row, col] + 1
                frontier.append((r, c))
    return distances


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


def model_policy(
    model_A: torch.nn.Module,
    model_B: torch.nn.Module,
    names: tuple[str, str] = ("model_A", "model_B"),
) -> PolicyFn:
    """Greedy actions and messages of two models that map raw observations [B, D] to
    (Q-values [B, 5], message [B, 1]); each model is called once per step on the batch.
    Non-finite Q-values or a message outside [0, 1] raise ValueError naming the model."""

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        outputs = []
        with torch.inference_mode():
            for agent, model in enumerate((model_A, model_B)):
                q_values, message = model(torch.from_numpy(np.ascontiguousarray(obs[:, agent])))
                q_values, message = q_values.numpy(), message.numpy()
                check_policy_outputs(q_values, message, names[agent])
                outputs.append((q_values.argmax(axis=1), message[:, 0]))
        actions = np.stack([outputs[0][0], outputs[1][0]], axis=1)
        return actions, np.stack([outputs[0][1], outputs[1][1]], axis=1)

    return act


def explore_by_step(
    policy_fn: PolicyFn,
    env: VectorMultiAgentEnv,
    epsilons: np.ndarray,
    episodes: int,
    seed: int = EVAL_SEED,
) -> PolicyFn:
    """ε-greedy around ``policy_fn`` with one exploration rate per copy of ``env``
    (``epsilons`` (N,)), copy c playing test episode ``c % episodes``. The uniform numbers
    and random actions are drawn once per (episode, step, agent) from ``seed``, so every
    copy of the same episode meets the same exploration draws at the same step (common
    random numbers: a run and an intervention on it differ only by the intervention)."""
    epsilons = np.asarray(epsilons, dtype=np.float64)
    if epsilons.shape != (env.n_envs,) or not ((epsilons >= 0) & (epsilons <= 1)).all():
        raise ValueError(f"epsilons must be {env.n_envs} numbers in [0, 1], got {epsilons}")
    rng = np.random.default_rng(seed)
    horizon = env.max_steps
    uniforms = rng.random((episodes, horizon, 2))
    random_actions = rng.integers(0, NUM_ACTIONS, (episodes, horizon, 2))
    row_starts = (np.arange(env.n_envs) % episodes) * horizon  # row e·T + t: episode e, step t
    threshold = epsilons[:, None]
    uniforms, random_actions = uniforms.reshape(-1, 2), random_actions.reshape(-1, 2)

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        actions, messages = policy_fn(obs, positions)
        rows = row_starts + np.minimum(env.steps, horizon - 1)
        explore = np.take(uniforms, rows, axis=0) < threshold
        return np.where(explore, np.take(random_actions, rows, axis=0), actions), messages

    return act


def start_positions(setting: EvaluationSetting, episodes: int, seed: int) -> np.ndarray:
    """Start cells (E, 2, 2) of the ``episodes`` test episodes drawn from ``seed`` (the cells
    a ``run_episodes(..., seed)`` round of E copies starts from)."""
    env = VectorMultiAgentEnv(
        episodes, grid=setting.grid, obs_window=setting.obs_window, max_steps=setting.max_steps
    )
    env.reset(seed=seed)
    return env.positions


def episode_summary(
    results: EpisodeResults, target: tuple[int, int], epsilon: float | None = None
) -> dict:
    """:func:`rollout.summarize` plus the exploration rate and, if the episodes were
    recorded, the failure shares."""
    summary: dict = summarize(results)
    if epsilon is not None:
        summary["epsilon"] = float(epsilon)
    if results.trajectories is not None:
        summary["failures"] = failure_shares(results, target)
    return summary


def mean_over_seeds(values: list[float | None]) -> dict[str, Any]:
    """Mean over the seeds that have a value (a seed without success has no steps to
    success), how many, and every seed's value."""
    present = [float(v) for v in values if v is not None]
    return {
        "mean": float(np.mean(present)) if present else None,
        "n": len(present),
        "per_seed": [None if v is None else float(v) for v in values],
    }
