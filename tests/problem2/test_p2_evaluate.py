"""Evaluation building blocks: baseline policies through the evaluator, bootstrap CIs,
the message perturbations of the causal test, exploration and failure kinds."""

from __future__ import annotations

import json

import numpy as np
import pytest
from analysis_episodes import (
    FAILURE_KINDS,
    classify_failures,
    perturb_messages,
    with_exploration,
)
from analysis_stats import bootstrap_ci, interquartile_mean, seed_statistics
from baselines import oracle_policy, random_policy
from evaluate import MultiAgentEvaluator
from models import MESSAGE_INDEX
from multi_agent_env import MultiAgentEnv, VectorMultiAgentEnv, generate_map
from rollout import EpisodeResults, run_episodes

from tests.conftest import PROBLEM2


@pytest.mark.parametrize("map_seed", [641, 0, 3])
def test_oracle_succeeds_always_through_the_evaluator(map_seed: int) -> None:
    evaluator = MultiAgentEvaluator(MultiAgentEnv(seed=map_seed), policy_factory=oracle_policy)
    performance = evaluator.evaluate_performance(num_episodes=400)
    assert performance["success_rate"] == 1.0
    assert performance["greedy"]["failures"]["failed_episodes"] == 0
    assert performance["eps"]["success_rate"] > 0.9  # random moves only delay it
    reward, success, info = evaluator.run_episode()
    assert success is True and isinstance(reward, float)
    assert info["steps"] == len(info["actions"]) == len(info["positions"]) - 1 <= 50


def test_random_policy_matches_baselines_json_within_noise() -> None:
    recorded = json.loads(
        (PROBLEM2 / "results" / "evaluation_results" / "baselines.json").read_text()
    )["maps"]["641"]["random"]
    evaluator = MultiAgentEvaluator(
        MultiAgentEnv(seed=641), policy_factory=lambda grid: random_policy(5)
    )
    summary = evaluator.evaluate_performance(num_episodes=2000)["greedy"]
    pooled = (summary["success_rate"] * 2000 + recorded["success_rate"] * 1000) / 3000
    noise = np.sqrt(max(pooled * (1 - pooled), 1e-3) * (1 / 2000 + 1 / recorded["episodes"]))
    assert abs(summary["success_rate"] - recorded["success_rate"]) < 4 * noise
    assert summary["mean_return"] == pytest.approx(recorded["mean_return_per_step"], abs=0.25)


def test_bootstrap_of_a_constant_sample_has_zero_width() -> None:
    assert bootstrap_ci([0.42] * 7) == (0.42, 0.42)
    assert bootstrap_ci([1.0]) == (1.0, 1.0)
    stats = seed_statistics([0.5, 0.5, 0.5])
    assert stats["mean"] == 0.5 and stats["ci95"] == [0.5, 0.5] and stats["iqm"] == 0.5


def test_bootstrap_agrees_with_naive_resampling() -> None:
    values = np.random.default_rng(1).normal(size=25)
    rng = np.random.default_rng(2)
    naive = values[rng.integers(0, 25, size=(40_000, 25))].mean(axis=1)
    expected = np.quantile(naive, [0.025, 0.975])
    assert np.allclose(bootstrap_ci(values, n_resamples=40_000), expected, atol=0.02)


def test_bootstrap_covers_a_binomial_mean_about_95_percent_of_the_time() -> None:
    rng = np.random.default_rng(3)
    p, n, trials = 0.3, 60, 400
    samples = rng.random((trials, n)) < p
    covered = [
        low <= p <= high
        for low, high in (bootstrap_ci(s, n_resamples=1000, seed=i) for i, s in enumerate(samples))
    ]
    assert 0.9 <= np.mean(covered) <= 0.99


def test_bootstrap_and_iqm_refuse_bad_input_and_handle_known_values() -> None:
    with pytest.raises(ValueError, match="at least one"):
        bootstrap_ci([])
    with pytest.raises(ValueError, match="finite"):
        bootstrap_ci([0.1, np.nan])
    assert interquartile_mean([0, 1, 2, 3, 4, 5, 6, 100]) == pytest.approx(3.5)
    assert interquartile_mean([1, 2, 3]) == pytest.approx(2.0)
    stats = seed_statistics([10.0, None, 12.0])
    assert stats["n"] == 2 and stats["mean"] == 11.0 and stats["per_seed"] == [10.0, None, 12.0]


def _recording_run(condition: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(observation given to the wrapper, observation the policy got, running mask) per step."""
    env = VectorMultiAgentEnv(64, seed=641)
    seen: list = []
    messages_rng = np.random.default_rng(0)
    inner_random = random_policy(1)

    def inner(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        seen[-1].append(obs.copy())
        actions, _ = inner_random(obs, positions)
        return actions, messages_rng.random((len(obs), 2))  # distinct messages

    wrapped = perturb_messages(inner, env, condition, seed=4)

    def outer(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        steps = env.steps
        seen.append([obs.copy(), steps == steps.max()])
        return wrapped(obs, positions)

    run_episodes(env, outer, 128, seed=5)
    return [(given, received, running) for given, running, received in seen]


def test_shuffled_message_changes_only_element_9_and_keeps_each_steps_multiset() -> None:
    records = _recording_run("shuffled")
    assert len(records) > 50  # two rounds
    changed_any = False
    for given, received, running in records:
        others = np.delete(np.arange(given.shape[-1]), MESSAGE_INDEX)
        assert np.array_equal(given[..., others], received[..., others])
        assert np.array_equal(given[~running], received[~running])
        for agent in range(2):
            before = given[running, agent, MESSAGE_INDEX]
            after = received[running, agent, MESSAGE_INDEX]
            assert np.array_equal(np.sort(before), np.sort(after))
            if running.sum() > 1 and np.unique(before).size == before.size:
                assert not np.any(before == after)  # always another episode's message
                changed_any = True
    assert changed_any


def test_zeroed_message_changes_only_element_9() -> None:
    for given, received, _ in _recording_run("zeroed"):
        assert np.all(received[..., MESSAGE_INDEX] == 0)
        others = np.delete(np.arange(given.shape[-1]), MESSAGE_INDEX)
        assert np.array_equal(given[..., others], received[..., others])


def test_unknown_message_condition_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown message condition"):
        perturb_messages(random_policy(0), VectorMultiAgentEnv(2, seed=0), "reversed")


def test_exploration_is_seeded_and_zero_epsilon_keeps_the_policy() -> None:
    grid = generate_map((10, 10), 641)
    env = VectorMultiAgentEnv(100, grid=grid)
    greedy = run_episodes(env, oracle_policy(grid), 100, seed=1)
    unexplored = run_episodes(env, with_exploration(oracle_policy(grid), 0.0, 7), 100, seed=1)
    assert np.array_equal(greedy.lengths, unexplored.lengths)
    runs = [
        run_episodes(env, with_exploration(oracle_policy(grid), 0.3, 7), 100, seed=1)
        for _ in range(2)
    ]
    assert np.array_equal(runs[0].returns, runs[1].returns)
    assert runs[0].lengths.mean() > greedy.lengths.mean()
    with pytest.raises(ValueError, match="epsilon"):
        with_exploration(oracle_policy(grid), 1.5)


def _episodes(paths_a: list, paths_b: list, successes: list[bool]) -> EpisodeResults:
    """Recorded results from per-episode position lists (T + 1 cells each agent)."""
    positions = np.stack([np.stack([a, b], axis=1) for a, b in zip(paths_a, paths_b, strict=True)])
    n, horizon = positions.shape[0], positions.shape[1] - 1
    return EpisodeResults(
        returns=np.zeros(n),
        successes=np.array(successes),
        lengths=np.full(n, horizon),
        trajectories={"positions": positions},
    )


def test_failure_kinds_on_hand_built_episodes() -> None:
    target, horizon = (5, 5), 20
    still = [(0, 0)] * (horizon + 1)
    on_target = [target] * (horizon + 1)
    swap_a = [(5, 5) if t % 2 == 0 else (5, 6) for t in range(horizon + 1)]
    swap_b = [(5, 6) if t % 2 == 0 else (5, 5) for t in range(horizon + 1)]
    wander = [(t % 10, (t * 3) % 7) for t in range(horizon + 1)]  # period 70 > window
    loop_b = [(2, 2 + t % 3) for t in range(horizon + 1)]
    came_and_left = [target] + [(5, 6)] * horizon  # B stood on the target at the start
    nudged = on_target[:15] + [(4, 5)] + on_target[16:]  # one random move off the target
    results = _episodes(
        [swap_a, on_target, still, wander, on_target, on_target, nudged, wander],
        [swap_b, still, loop_b, still, came_and_left, wander, wander, wander],
        [False, False, False, False, False, False, False, True],
    )
    kinds = classify_failures(results, target)
    names = [FAILURE_KINDS[k] if k >= 0 else "success" for k in kinds]
    expected = ["swapping", "parked", "looping", "other", "looping", "parked", "parked"]
    assert names == expected + ["success"]
