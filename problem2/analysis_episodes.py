"""Running trained policies for Problem 2's evaluation: greedy policies from two models,
exploration with common random numbers, fixed start cells, per-episode summaries, the
classification and the decomposition of failed episodes.

Every policy here has the ``rollout.PolicyFn`` signature, so random, oracle and trained
policies all run through :func:`rollout.run_episodes`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from analysis_runs import check_policy_outputs
from multi_agent_env import NUM_ACTIONS, VectorMultiAgentEnv
from rollout import EVAL_SEED, EpisodeResults, PolicyFn, summarize

MAX_BATCH = 20_000  # copies stepped together (test episodes x blocks); more run in groups
FAILURE_KINDS = ("swapping", "parked", "looping", "other")
FAILURE_WINDOW = 10  # the last steps of a failed episode that its classification looks at
LOOP_CELLS = 4  # at most this many distinct cells per agent in the window: looping
PARKED_SHARE = 0.5  # on the target at least this share of the window: parked
SWAP_RADIUS = 2  # Manhattan distance from the target within which a swap counts


@dataclass(frozen=True)
class EvaluationSetting:
    """The map and episode rules an evaluation runs on."""

    grid: np.ndarray  # (H, W) int: 0 free, 1 obstacle, 2 target
    reward_mode: str = "arrival"
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
    rows = np.arange(env.n_envs) % episodes
    threshold = epsilons[:, None]

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        actions, messages = policy_fn(obs, positions)
        steps = np.minimum(env.steps, horizon - 1)
        explore = uniforms[rows, steps] < threshold
        return np.where(explore, random_actions[rows, steps], actions), messages

    return act


def start_positions(setting: EvaluationSetting, episodes: int, seed: int) -> np.ndarray:
    """Start cells (E, 2, 2) of the ``episodes`` test episodes drawn from ``seed`` (the cells
    a ``run_episodes(..., seed)`` round of E copies starts from)."""
    env = VectorMultiAgentEnv(
        episodes, grid=setting.grid, obs_window=setting.obs_window, max_steps=setting.max_steps
    )
    env.reset(seed=seed)
    return env.positions


def classify_failures(results: EpisodeResults, target: tuple[int, int]) -> np.ndarray:
    """Failure kind of each episode (E,) as an index into ``FAILURE_KINDS``; −1 on success.

    A failed episode ran the full ``T`` steps; its window, the last ``FAILURE_WINDOW`` steps
    (W, so W + 1 positions), is examined and the first matching kind, in this order, is its
    kind (the thresholds leave room for the odd random move of an ε-greedy policy):

    * ``swapping``: at least two of the W steps are swaps — each agent moves into the cell
      the other just left — between cells within Manhattan distance ``SWAP_RADIUS`` of the
      target (the two agents keep trading places next to it);
    * ``parked``: one agent is on the target at the last position and at least a share
      ``PARKED_SHARE`` of the window's positions, and the other never stood on it in the
      whole episode;
    * ``looping``: each agent visits at most ``LOOP_CELLS`` distinct cells in the window
      (both keep moving among a few cells, or stand still);
    * ``other``: none of these (e.g. still wandering when time ran out).

    Needs ``results`` recorded (``record=True``).
    """
    if results.trajectories is None:
        raise ValueError("classify_failures needs recorded episodes (record=True)")
    positions = results.trajectories["positions"]  # (E, T + 1, 2, 2)
    window = positions[:, -(FAILURE_WINDOW + 1) :]  # (E, W + 1, 2, 2)
    target = np.asarray(target)
    before, after = window[:, :-1], window[:, 1:]
    swaps = (
        np.all(after[:, :, 0] == before[:, :, 1], axis=-1)
        & np.all(after[:, :, 1] == before[:, :, 0], axis=-1)
        & np.any(before[:, :, 0] != before[:, :, 1], axis=-1)
        & np.all(np.abs(before - target).sum(axis=-1) <= SWAP_RADIUS, axis=-1)
    )  # (E, W)
    on_target = np.all(window == target, axis=-1)  # (E, W + 1, 2)
    ever_on_target = np.all(positions == target, axis=-1).any(axis=1)  # (E, 2)
    stays = on_target[:, -1] & (on_target.mean(axis=1) >= PARKED_SHARE)  # (E, 2)
    parked = (stays & ~ever_on_target[:, ::-1]).any(axis=1)
    cells = window[..., 0] * (positions[..., 1].max() + 1) + window[..., 1]  # (E, W + 1, 2)
    ordered = np.sort(cells, axis=1)
    distinct = 1 + (np.diff(ordered, axis=1) != 0).sum(axis=1)  # (E, 2)
    looping = np.all(distinct <= LOOP_CELLS, axis=1)
    kinds = np.select(
        [swaps.sum(axis=1) >= 2, parked, looping], [0, 1, 2], default=FAILURE_KINDS.index("other")
    )
    return np.where(results.successes, -1, kinds)


def failure_shares(
    results: EpisodeResults, target: tuple[int, int]
) -> dict[str, float | int | None]:
    """Number of failed episodes and the share of each kind among them (None if none
    failed)."""
    kinds = classify_failures(results, target)
    failed = kinds[kinds >= 0]
    shares: dict[str, float | int | None] = {"failed_episodes": int(failed.size)}
    for index, kind in enumerate(FAILURE_KINDS):
        shares[kind] = float(np.mean(failed == index)) if failed.size else None
    return shares


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


DECOMPOSITION = {
    "navigation": "a failed episode in which at least one agent never reached the target",
    "timing": "a failed episode in which both agents reached the target, never on the same step",
    "reached_and_left": "a failed episode in which an agent stepped off the target after "
    "reaching it (overlaps the two kinds above)",
    "stay_on_target_share": "share of the steps begun by an agent on the target on which it is "
    "still there after the step (all episodes)",
}


def failure_decomposition(results: EpisodeResults, target: tuple[int, int]) -> dict:
    """Shares of the failed episodes by ``DECOMPOSITION`` (None if none failed) and the share
    of on-target steps on which the agent stays. Needs recorded episodes."""
    if results.trajectories is None:
        raise ValueError("failure_decomposition needs recorded episodes (record=True)")
    positions = results.trajectories["positions"]  # (E, T + 1, 2, 2)
    horizon = positions.shape[1] - 1
    on = np.all(positions == np.asarray(target), axis=-1)  # (E, T + 1, 2)
    failed = ~results.successes
    reached = on.any(axis=1)  # (E, 2)
    left = (on[:, :-1] & ~on[:, 1:]).any(axis=(1, 2))
    taken = (np.arange(horizon)[None, :] < results.lengths[:, None])[..., None]  # (E, T, 1)
    began_on = on[:, :-1] & taken
    count = int(failed.sum())

    def share(kind: np.ndarray) -> float | None:
        return float((kind & failed).sum() / count) if count else None

    return {
        "failed_episodes": count,
        "navigation": share(~reached.all(axis=1)),
        "timing": share(reached.all(axis=1)),
        "reached_and_left": share(left),
        "stay_on_target_share": float((began_on & on[:, 1:]).sum() / began_on.sum())
        if began_on.any()
        else None,
        "steps_begun_on_target": int(began_on.sum()),
    }
