"""``MultiAgentEvaluator``: the course's evaluation interface for a pair of agents (or any
policy) on one map, built on the vectorised environment. Re-exported by ``evaluate.py``.

The analyses beyond the course's (``python -m analysis.pipeline``) run through the same
:meth:`MultiAgentEvaluator.run_blocks`: the interventions of ``analysis/interventions.py``
and the other policies of ``analysis/generalization.py`` change the policy of some blocks
through its ``wrap`` argument."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from multi_agent_env import MultiAgentEnv, render_state
from rollout import (
    EVAL_EPSILON,
    EVAL_SEED,
    EpisodeResults,
    PolicyFn,
    run_episodes,
    summarize,
)
from vector_env import ACTION_NAMES, VectorMultiAgentEnv, generate_map

from analysis.episodes import (
    MAX_BATCH,
    EvaluationSetting,
    episode_summary,
    explore_by_step,
    model_policy,
    oracle_policy,
    recorded_episodes,
    start_positions,
)
from analysis.messages import mean_message_per_cell, message_correlations, message_distribution
from analysis.plots import plot_message_heatmap, plot_trajectories, representative_traces
from analysis.runs import Experiment, check_policy, load_model_pair, model_paths

GENERALIZATION_MAP_SEEDS = tuple(range(10))
PolicyFactory = Callable[[np.ndarray], PolicyFn]  # map (H, W) -> greedy policy on that map
# (policy of the blocks stepped together, their environment, the blocks' indices) -> the
# policy they act with instead (see ``MultiAgentEvaluator.run_blocks``)
BlockWrap = Callable[[PolicyFn, VectorMultiAgentEnv, range], PolicyFn]


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
        )
        for k in range(blocks)
    ]


class MultiAgentEvaluator:
    """Evaluates a pair of agents, or any policy, on the map of ``env``.

    Args:
        env: a ``MultiAgentEnv`` or ``VectorMultiAgentEnv``; its map, time limit, window
            and reward mode are used (the evaluator builds its own vectorised copies).
        model_A, model_B: modules mapping raw observations [B, 11] to (Q-values [B, 5],
            message [B, 1] in [0, 1]): TorchScript files from :func:`load_trained_models`
            (mask inside) or plain ``AgentDQN`` / ``DuelingDQN`` instances (fed the raw
            observation, as they are). Checked on probe observations first; non-finite
            Q-values or messages outside [0, 1] are a ValueError naming the model.
        policy_factory: instead of models, a function from a map (H, W) to a greedy
            ``rollout.PolicyFn`` (e.g. ``baselines.oracle_policy``).
        epsilon: exploration rate of the ε-greedy condition (the other is greedy).
        seed: seed of the test episodes' start cells and of the exploration stream.
    """

    def __init__(
        self,
        env: MultiAgentEnv | VectorMultiAgentEnv,
        model_A: torch.nn.Module | None = None,
        model_B: torch.nn.Module | None = None,
        *,
        policy_factory: PolicyFactory | None = None,
        epsilon: float = EVAL_EPSILON,
        seed: int = EVAL_SEED,
        names: tuple[str, str] = ("model_A", "model_B"),
    ) -> None:
        if policy_factory is None and (model_A is None or model_B is None):
            raise ValueError("give model_A and model_B, or a policy_factory")
        if policy_factory is None:
            for model, name in zip((model_A, model_B), names, strict=True):
                check_policy(model, name, env.obs_window**2 + 2)
        self.setting = EvaluationSetting(
            np.asarray(env.grid), env.reward_mode, env.max_steps, env.obs_window
        )
        self.model_A, self.model_B = model_A, model_B
        self.policy_factory = policy_factory or (lambda grid: model_policy(model_A, model_B, names))
        self.epsilon, self.seed = float(epsilon), int(seed)
        self.conditions = {"greedy": 0.0, "eps": self.epsilon}
        self._episodes_run = 0

    # --------------------------------------------------------------------- running
    def run_blocks(
        self,
        num_episodes: int,
        epsilons: list[float],
        wrap: BlockWrap | None = None,
        record: bool = False,
        setting: EvaluationSetting | None = None,
    ) -> list[EpisodeResults]:
        """The same ``num_episodes`` test episodes (start cells from ``self.seed``) once per
        block, all blocks stepped together, block k exploring with ``epsilons[k]``. ``wrap``,
        if given, changes the greedy policy of each group of blocks stepped together before
        exploration (what an agent hears, ``analysis/interventions.py``; other policies in
        some blocks, ``analysis/generalization.py``). Exploration uses common random
        numbers: two blocks differ only by their policy and exploration rate."""
        setting = setting or self.setting
        blocks = len(epsilons)
        starts = start_positions(setting, num_episodes, self.seed)
        per_group = max(1, MAX_BATCH // num_episodes)
        results: list[EpisodeResults] = []
        for first in range(0, blocks, per_group):
            group = range(first, min(first + per_group, blocks))
            env = setting.make_env(num_episodes * len(group))
            policy = self.policy_factory(setting.grid)
            if wrap is not None:
                policy = wrap(policy, env, group)
            rates = np.repeat([epsilons[k] for k in group], num_episodes)
            policy = explore_by_step(policy, env, rates, num_episodes, self.seed)
            both = np.tile(starts, (len(group), 1, 1))
            run_all = recorded_episodes if record else run_episodes
            run = run_all(env, policy, len(both), start_positions=both)
            results += split_blocks(run, len(group))
        return results

    def run(
        self,
        num_episodes: int,
        epsilon: float = 0.0,
        record: bool = True,
        setting: EvaluationSetting | None = None,
    ) -> EpisodeResults:
        """``num_episodes`` fixed test episodes, ε-greedy with ``epsilon``, on ``setting``
        (default: own map)."""
        return self.run_blocks(num_episodes, [epsilon], record=record, setting=setting)[0]

    def run_conditions(self, num_episodes: int) -> dict[str, EpisodeResults]:
        """Recorded episodes of the greedy and the ε-greedy condition."""
        runs = self.run_blocks(num_episodes, list(self.conditions.values()), record=True)
        return dict(zip(self.conditions, runs, strict=True))

    def run_episode(
        self, render: bool = False, epsilon: float = 0.0
    ) -> tuple[float, bool, dict[str, Any]]:
        """One episode (a new start on each call, reproducibly); ``render`` prints every
        step. Returns (return, success, info with steps, positions, actions, messages)."""
        env = self.setting.make_env(1)
        policy = explore_by_step(
            self.policy_factory(self.setting.grid), env, np.array([epsilon]), 1, self.seed
        )
        seed = self.seed + 10_000 + self._episodes_run
        self._episodes_run += 1
        run = recorded_episodes(env, policy, 1, seed=seed)
        steps, trajectories = int(run.lengths[0]), run.trajectories
        positions = trajectories["positions"][0, : steps + 1]
        actions, messages = trajectories["actions"][0, :steps], trajectories["messages"][0, :steps]
        info: dict[str, Any] = {
            "steps": steps,
            "positions": positions.tolist(),
            "actions": [[ACTION_NAMES[a] for a in pair] for pair in actions],
            "messages": messages.astype(float).tolist(),
        }
        success = bool(run.successes[0])
        if render:
            grid, limit = self.setting.grid, self.setting.max_steps
            print(render_state(grid, positions[0], 0, limit, (0.0, 0.0)))
            for t in range(steps):
                print(
                    f"actions A {info['actions'][t][0]}, B {info['actions'][t][1]}; "
                    f"reward {float(trajectories['rewards'][0, t]):+.1f}"
                )
                print(render_state(grid, positions[t + 1], t + 1, limit, messages[t]))
            print("success: both agents on the target" if success else "failure: time ran out")
        return float(run.returns[0]), success, info

    # ------------------------------------------------------------------ analyses
    def summaries(self, runs: dict[str, EpisodeResults]) -> dict[str, dict[str, Any]]:
        """Per condition (greedy, ε) of ``runs``: success rate, mean steps to success, mean
        return, the exploration rate and the failure shares (``analysis/failures.py``)."""
        target = self.setting.target
        return {name: episode_summary(runs[name], target, self.conditions[name]) for name in runs}

    def evaluate_performance(self, num_episodes: int = 100) -> dict[str, Any]:
        """:meth:`summaries` of ``num_episodes`` test episodes, greedy and ε-greedy; the
        top-level numbers are the greedy ones."""
        report = self.summaries(self.run_conditions(num_episodes))
        return {**{k: v for k, v in report["greedy"].items() if k != "failures"}, **report}

    def analyze_communication(
        self, num_episodes: int = 20, recorded: EpisodeResults | None = None
    ) -> dict[str, Any]:
        """Message distribution per agent and its correlations with what the sender sees and
        where it stands, on greedy test episodes. (Whether the partner uses the message:
        ``analysis.interventions.intervention_test``, run by ``python -m analysis.pipeline``.)"""
        recorded = recorded or self.run(num_episodes)
        return {
            "episodes": num_episodes,
            "messages": message_distribution(recorded),
            "correlations": message_correlations(recorded, self.setting.grid),
        }

    def visualize_trajectory(
        self, save_path: str | Path = "results/trajectory.png", num_episodes: int = 200
    ) -> Path:
        """Draw a representative successful and a failed test episode (greedy if the
        greedy policy has both, otherwise taken from the ε-greedy episodes)."""
        traces = representative_traces(self.run_conditions(num_episodes), self.setting.target)
        return plot_trajectories([("evaluated policy", traces)], self.setting.grid, save_path)

    def plot_communication_heatmap(
        self, save_path: str | Path = "results/comm_heatmap.png", num_episodes: int = 500
    ) -> Path:
        """Mean message sent by each agent from each cell over greedy test episodes."""
        means = mean_message_per_cell(self.run(num_episodes), self.setting.grid.shape)
        return plot_message_heatmap([("evaluated policy", means)], self.setting.grid, save_path)

    def test_generalization(
        self,
        num_configs: int = 10,
        num_episodes: int = 500,
        oracle: bool = True,
        map_seeds: Sequence[int] | None = None,
    ) -> dict[str, Any]:
        """Success greedy and ε-greedy on map seeds 0 .. num_configs − 1, or on ``map_seeds``
        if given (maps the models never saw; same size and rules), beside the shortest-path
        oracle on each map (``oracle=False`` leaves it out). ``mean_greedy`` / ``mean_eps``:
        over the maps."""
        map_seeds = list(range(num_configs) if map_seeds is None else map_seeds)
        maps: dict[str, dict] = {}
        for map_seed in map_seeds:
            grid = generate_map(self.setting.grid.shape, map_seed)
            setting = EvaluationSetting(grid, *self._rules())
            entry: dict[str, Any] = {"target": list(setting.target)}
            runs = self.run_blocks(num_episodes, list(self.conditions.values()), setting=setting)
            for name, results in zip(self.conditions, runs, strict=True):
                entry[name] = float(results.successes.mean())
            if oracle:
                entry["oracle"] = summarize(
                    run_episodes(
                        setting.make_env(num_episodes), oracle_policy(grid), num_episodes, self.seed
                    )
                )
            maps[str(map_seed)] = entry
        means = {
            f"mean_{n}": float(np.mean([m[n] for m in maps.values()])) for n in self.conditions
        }
        return {
            "map_seeds": map_seeds,
            "episodes": num_episodes,
            "maps": maps,
        } | means

    def _rules(self) -> tuple[str, int, int]:
        return self.setting.reward_mode, self.setting.max_steps, self.setting.obs_window


def experiment_evaluator(
    experiment: Experiment,
    epsilon: float,
    mode: str | None = None,
    seed: int | None = None,
    models_dir: Path | None = None,
    **kw,
) -> MultiAgentEvaluator:
    """An evaluator on ``experiment``'s map and time limit: of the pair (``mode``, ``seed``)
    loaded from ``models_dir`` (default: the experiment's models folder), or, without
    ``mode``, of ``kw["policy_factory"]``."""
    settings = experiment.settings
    # Returns are reported under the assignment's reward (the env's default), whatever
    # reward the agents were trained on; success does not depend on the reward.
    env = MultiAgentEnv(grid=experiment.grid, max_steps=int(settings["max_steps"]))
    if mode is None:
        return MultiAgentEvaluator(env, epsilon=epsilon, **kw)
    models_dir = experiment.models_dir if models_dir is None else models_dir
    models = load_model_pair(models_dir, mode, seed)
    names = tuple(str(path) for path in model_paths(models_dir, mode, seed))
    return MultiAgentEvaluator(env, *models, epsilon=epsilon, names=names, **kw)
