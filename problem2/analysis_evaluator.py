"""``MultiAgentEvaluator``: the course's evaluation interface for a pair of agents (or any
policy) on one map, built on the vectorised environment. Re-exported by ``evaluate.py``."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from analysis_episodes import (
    MESSAGE_CONDITIONS,
    EvaluationSetting,
    episode_summary,
    model_policy,
    perturb_messages,
    with_exploration,
)
from analysis_interventions import intervene
from analysis_messages import mean_message_per_cell, message_correlations, message_distribution
from analysis_plots import plot_message_heatmap, plot_trajectories
from analysis_runs import check_policy
from analysis_stats import paired_difference
from analysis_traces import representative_traces
from baselines import oracle_policy
from grid_maps import ACTION_NAMES, generate_map
from multi_agent_env import MultiAgentEnv, VectorMultiAgentEnv
from rollout import EVAL_EPSILON, EVAL_SEED, EpisodeResults, PolicyFn, run_episodes, summarize

GENERALIZATION_MAP_SEEDS = tuple(range(10))
PolicyFactory = Callable[[np.ndarray], PolicyFn]  # map (H, W) -> greedy policy on that map


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
    def run(
        self,
        num_episodes: int,
        epsilon: float = 0.0,
        message: str = "real",
        record: bool = True,
        setting: EvaluationSetting | None = None,
        intervention: tuple[int, np.ndarray | None] | None = None,
    ) -> EpisodeResults:
        """``num_episodes`` fixed test episodes (one batch), ε-greedy with ``epsilon``,
        the incoming message real, shuffled or zeroed; on ``setting`` (default: own map).
        ``intervention`` = (observation index, table (E, T, 2)) feeds the table's values
        on that element (see ``analysis_interventions``)."""
        setting = setting or self.setting
        env = setting.make_env(num_episodes)
        policy = perturb_messages(self.policy_factory(setting.grid), env, message, self.seed + 1)
        if intervention is not None:
            policy = intervene(policy, env, intervention[1], intervention[0])
        policy = with_exploration(policy, epsilon, self.seed)
        return run_episodes(env, policy, num_episodes, self.seed, record)

    def run_conditions(self, num_episodes: int) -> dict[str, EpisodeResults]:
        """Recorded episodes of the greedy and the ε-greedy condition."""
        return {name: self.run(num_episodes, eps) for name, eps in self.conditions.items()}

    def run_episode(
        self, render: bool = False, epsilon: float = 0.0
    ) -> tuple[float, bool, dict[str, Any]]:
        """One episode (a new start on each call, reproducibly); ``render`` prints every
        step. Returns (return, success, info with steps, positions, actions, messages)."""
        env = VectorMultiAgentEnv(
            1,
            grid=self.setting.grid,
            obs_window=self.setting.obs_window,
            max_steps=self.setting.max_steps,
            reward_mode=self.setting.reward_mode,
            auto_reset=False,
        )
        policy = with_exploration(self.policy_factory(self.setting.grid), epsilon, self.seed)
        obs = env.reset(seed=self.seed + 10_000 + self._episodes_run)
        self._episodes_run += 1
        info: dict[str, Any] = {"positions": [env.positions[0].tolist()], "actions": []}
        info["messages"], total, done, terminated = [], 0.0, False, False
        if render:
            env.render()
        while not done:
            actions, messages = policy(obs, env.positions)
            obs, reward, terminated_, truncated, _ = env.step(actions, messages)
            total += float(reward[0])
            terminated, done = bool(terminated_[0]), bool(terminated_[0] or truncated[0])
            info["positions"].append(env.positions[0].tolist())
            info["actions"].append([ACTION_NAMES[a] for a in actions[0]])
            info["messages"].append([float(m) for m in messages[0]])
            if render:
                print(f"actions A {info['actions'][-1][0]}, B {info['actions'][-1][1]}; "
                      f"reward {float(reward[0]):+.1f}")  # fmt: skip
                env.render()
        info["steps"] = len(info["actions"])
        if render:
            print("success: both agents on the target" if terminated else "failure: time ran out")
        return total, terminated, info

    # ------------------------------------------------------------------ analyses
    def evaluate_performance(self, num_episodes: int = 100) -> dict[str, Any]:
        """Success rate, mean steps to success, mean return and failure shares, greedy
        and ε-greedy; the top-level numbers are the greedy ones."""
        results = self.run_conditions(num_episodes)
        target = self.setting.target
        report = {
            name: episode_summary(results[name], target, eps)
            for name, eps in self.conditions.items()
        }
        return {**{k: v for k, v in report["greedy"].items() if k != "failures"}, **report}

    def causal_message_test(
        self, num_episodes: int, real: dict[str, EpisodeResults] | None = None
    ) -> dict[str, dict]:
        """Success with the real, the shuffled and the zeroed incoming message, per
        condition, with the paired (same start cells) differences and their episode-level
        bootstrap CIs. ``real`` reuses already run real-message episodes."""
        real = real or self.run_conditions(num_episodes)
        test: dict[str, dict] = {}
        for name, eps in self.conditions.items():
            successes = {"real": real[name].successes}
            for message in MESSAGE_CONDITIONS[1:]:
                successes[message] = self.run(num_episodes, eps, message, record=False).successes
            test[name] = {m: float(s.mean()) for m, s in successes.items()}
            for message in MESSAGE_CONDITIONS[1:]:
                test[name][f"real_minus_{message}"] = paired_difference(
                    successes["real"], successes[message]
                )
        return test

    def analyze_communication(
        self, num_episodes: int = 20, recorded: EpisodeResults | None = None
    ) -> dict[str, Any]:
        """Message distribution per agent, its correlations with what the sender sees (on
        greedy episodes), and the causal test (:meth:`causal_message_test`)."""
        recorded = recorded or self.run(num_episodes)
        return {
            "episodes": num_episodes,
            "messages": message_distribution(recorded),
            "correlations": message_correlations(recorded, self.setting.grid),
            "causal": self.causal_message_test(num_episodes),
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
        self, num_configs: int = 10, num_episodes: int = 500, oracle: bool = True
    ) -> dict[str, Any]:
        """Success greedy and ε-greedy on map seeds 0 .. num_configs − 1 (maps the models
        never saw; same size and rules), beside the shortest-path oracle on each map
        (``oracle=False`` leaves it out). ``mean_greedy`` / ``mean_eps``: over the maps."""
        maps: dict[str, dict] = {}
        for map_seed in range(num_configs):
            grid = generate_map(self.setting.grid.shape, map_seed)
            setting = EvaluationSetting(grid, *self._rules())
            entry: dict[str, Any] = {"target": list(setting.target)}
            for name, eps in self.conditions.items():
                results = self.run(num_episodes, eps, record=False, setting=setting)
                entry[name] = float(results.successes.mean())
            if oracle:
                env = setting.make_env(num_episodes)
                entry["oracle"] = summarize(
                    run_episodes(env, oracle_policy(grid), num_episodes, self.seed)
                )
            maps[str(map_seed)] = entry
        means = {
            f"mean_{n}": float(np.mean([m[n] for m in maps.values()])) for n in self.conditions
        }
        return {
            "map_seeds": list(range(num_configs)),
            "episodes": num_episodes,
            "maps": maps,
        } | means

    def _rules(self) -> tuple[str, int, int]:
        return self.setting.reward_mode, self.setting.max_steps, self.setting.obs_window
