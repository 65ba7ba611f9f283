"""Evaluation building blocks: baseline policies through the evaluator, bootstrap CIs,
the channel interventions, exploration, failure kinds and decomposition, information
measures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from analysis.arrivals import arrivals, failure_decomposition
from analysis.baselines import POLICIES, explorer_policy, random_policy
from analysis.episodes import oracle_policy
from analysis.failures import FAILURE_KINDS, classify_failures, on_target
from analysis.generalization import block_policy
from analysis.information import causal_influence, mutual_information
from analysis.interventions import (
    INTERVENTIONS,
    channel_verdict,
    intervene,
    intervention_table,
    real_steps,
    received_values,
    stack_tables,
)
from analysis.plots import EpisodeTrace, waiting_steps
from analysis.stats import bootstrap_ci, interquartile_mean, mode_differences, seed_statistics
from evaluate import MultiAgentEvaluator
from multi_agent_env import MultiAgentEnv
from rollout import EpisodeResults, run_episodes, select_best, summarize
from vector_env import MESSAGE_INDEX, VectorMultiAgentEnv

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


def _real_run(episodes: int = 200) -> tuple[MultiAgentEvaluator, EpisodeResults]:
    """Random actions with distinct messages on map 641, recorded."""

    def factory(grid: np.ndarray):
        rng = np.random.default_rng(3)

        def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return rng.integers(0, 5, (len(obs), 2)), rng.random((len(obs), 2))

        return act

    evaluator = MultiAgentEvaluator(MultiAgentEnv(seed=641), policy_factory=factory)
    return evaluator, evaluator.run(episodes)


def test_mode_differences_pair_by_episode_and_name_the_established_ones() -> None:
    rng = np.random.default_rng(0)
    easy = rng.random(1000) < 0.6  # episodes that every seed of every mode solves
    base = np.tile(easy, (10, 1))
    worse = base.copy()
    worse[:, np.flatnonzero(easy)[:30]] = False  # 30 easy episodes lost by every seed
    noisy = rng.random((5, 1000)) < 0.6  # unrelated to the episodes' difficulty
    result = mode_differences({"worse": worse, "base": base, "noisy": noisy}, n_resamples=2000)
    assert list(result) == ["base_minus_worse", "noisy_minus_worse", "noisy_minus_base"]
    gain = result["base_minus_worse"]
    assert gain["mean"] == pytest.approx(0.03) and gain["ci95_seeds_only"] == [
        pytest.approx(0.03),
        pytest.approx(0.03),
    ]
    # paired: the episodes' difficulty cancels, only the 30 flipped episodes vary
    assert gain["established"] and 0.015 < gain["ci95"][0] <= 0.03 <= gain["ci95"][1] < 0.045
    assert gain["seeds"] == [10, 10] and gain["episodes"] == 1000
    same = mode_differences({"a": base, "b": base}, n_resamples=500)["b_minus_a"]
    assert same["mean"] == 0 and same["ci95"] == [0, 0] and not same["established"]
    with pytest.raises(ValueError, match="same E"):
        mode_differences({"a": base, "b": base[:, :10]})


def test_block_policy_gives_each_block_its_own_policy() -> None:
    def constant(action: int):
        return lambda grid: (
            lambda obs, pos: (np.full((len(obs), 2), action), np.zeros((len(obs), 2)))
        )

    one, two = constant(1), constant(2)
    policy = block_policy([one, one, two], np.zeros((3, 3)), 4)
    actions, messages = policy(np.zeros((12, 2, 11)), np.zeros((12, 2, 2), dtype=np.int64))
    assert actions[:, 0].tolist() == [1] * 8 + [2] * 4 and messages.shape == (12, 2)


@pytest.mark.parametrize("kind", [k for k in INTERVENTIONS if k != "real"])
def test_intervention_tables_hold_what_their_name_says(kind: str) -> None:
    _, real = _real_run()
    received = received_values(real, MESSAGE_INDEX)  # (E, T, 2)
    taken = real_steps(real)
    table = intervention_table(kind, real, MESSAGE_INDEX, constant=0.37, seed=1)
    assert table.shape == received.shape and np.isfinite(table).all()
    if kind.startswith("constant"):
        expected = {"constant_mean": 0.37, "constant_0": 0.0, "constant_1": 1.0}[kind]
        assert np.all(table == np.float32(expected))
    elif kind == "random_step":
        pool = set(received[taken].ravel().tolist())
        assert set(table.ravel().tolist()) <= pool
    elif kind == "shuffled_time":
        for e in range(len(table)):
            length = real.lengths[e]
            own = np.sort(received[e, :length], axis=0)
            assert np.array_equal(np.sort(table[e, :length], axis=0), own)  # a permutation
    else:  # same_step: another running episode's value at the same step
        for t in (1, 5, 20):
            running = np.flatnonzero(taken[:, t])
            for e in range(len(table)):
                donors = np.flatnonzero(np.all(received[running, t] == table[e, t], axis=-1))
                assert donors.size and not np.array_equal(running[donors], [e])


def test_intervention_changes_only_its_element_and_keeps_the_real_value_on_nan() -> None:
    evaluator, real = _real_run(64)
    env = VectorMultiAgentEnv(128, grid=evaluator.setting.grid)
    table = intervention_table("constant_1", real, MESSAGE_INDEX)
    stacked = stack_tables([None, table], 64, evaluator.setting)
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    def inner(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        seen[-1] = (seen[-1], obs.copy())
        return np.full((len(obs), 2), 4), np.zeros((len(obs), 2))

    wrapped = intervene(inner, env, stacked, MESSAGE_INDEX)

    def outer(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        seen.append(obs.copy())
        return wrapped(obs, positions)

    run_episodes(env, outer, 128, seed=5, start_positions=np.tile(env.positions[:64], (2, 1, 1)))
    for given, received in seen:
        others = np.delete(np.arange(given.shape[-1]), MESSAGE_INDEX)
        assert np.array_equal(given[..., others], received[..., others])
        assert np.array_equal(given[:64], received[:64])
        assert np.all(received[64:, :, MESSAGE_INDEX] == 1.0)


def test_unknown_intervention_is_refused() -> None:
    _, real = _real_run(8)
    with pytest.raises(ValueError, match="unknown intervention"):
        intervention_table("reversed", real, MESSAGE_INDEX)


def test_channel_verdicts() -> None:
    zero, hurt = {"mean": 0.0, "ci95": [-0.01, 0.01]}, {"mean": -0.2, "ci95": [-0.3, -0.1]}
    assert channel_verdict({"same_step": hurt, "constant_0": hurt}) == "content"
    assert channel_verdict({"same_step": zero, "random_step": hurt}) == "clock"
    assert channel_verdict({"same_step": zero, "shuffled_time": hurt}) == "clock"
    assert channel_verdict({"same_step": zero, "random_step": zero, "constant_1": hurt}) == (
        "presence"
    )
    assert channel_verdict({"same_step": zero, "constant_mean": zero}) == "none"


def test_exploration_uses_common_random_numbers_and_zero_epsilon_keeps_the_policy() -> None:
    evaluator = MultiAgentEvaluator(MultiAgentEnv(seed=641), policy_factory=oracle_policy)
    greedy, explored, again = evaluator.run_blocks(100, [0.0, 0.3, 0.3])
    alone = evaluator.run(100, 0.0, record=False)
    assert np.array_equal(greedy.lengths, alone.lengths) and greedy.successes.all()
    assert np.array_equal(explored.lengths, again.lengths)  # same episode, same draws
    assert explored.lengths.mean() > greedy.lengths.mean()
    with pytest.raises(ValueError, match="epsilons"):
        evaluator.run(10, 1.5)


def test_explorers_succeed_sometimes_and_the_sweep_more_often() -> None:
    rates = {}
    for name in ("random", "explorer", "sweep_explorer"):
        evaluator = MultiAgentEvaluator(
            MultiAgentEnv(seed=0), policy_factory=lambda grid, n=name: POLICIES[n](grid, 1)
        )
        rates[name] = evaluator.run(1000, record=False).successes.mean()
    assert rates["random"] < 0.05 < rates["explorer"] < rates["sweep_explorer"] < 0.9


def test_explorer_steps_onto_a_visible_target_and_stays() -> None:
    obs = np.zeros((3, 2, 11), dtype=np.float32)
    obs[0, :, 1] = 2  # target above
    obs[1, :, 4] = 2  # standing on it
    obs[2, :, 8] = 2  # below right; the cell below is open: move down first
    actions, messages = explorer_policy(0)(obs, np.zeros((3, 2, 2), dtype=np.int64))
    assert actions.tolist() == [[0, 0], [4, 4], [1, 1]] and np.all(messages == 0)


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


def test_failure_decomposition_on_hand_built_episodes() -> None:
    target, horizon = (5, 5), 20
    still = [(0, 0)] * (horizon + 1)
    on_target = [target] * (horizon + 1)
    left = [target] * 5 + [(5, 6)] * (horizon - 4)
    results = _episodes(
        [still, on_target, left, on_target],
        [still, still, [(5, 6)] * 10 + [target] + [(5, 6)] * (horizon - 10), on_target],
        [False, False, False, True],
    )
    shares = failure_decomposition(results, target)
    assert shares["failed_episodes"] == 3
    assert shares["navigation"] == pytest.approx(2 / 3) and shares["timing"] == pytest.approx(1 / 3)
    assert shares["reached_and_left"] == pytest.approx(1 / 3)
    # steps begun on the target: 20 (episode 2) + 5 + 1 (episode 3) + 40 (success); stays: 64
    assert shares["steps_begun_on_target"] == 66
    assert shares["stay_on_target_share"] == pytest.approx(64 / 66)
    # by agent: A began 20 + 5 + 20 steps on the target and stayed 44; B began 1 + 20, stayed 20
    assert shares["stay_share_more_staying"] == pytest.approx(44 / 45)
    assert shares["stay_share_less_staying"] == pytest.approx(20 / 21)


def test_stay_shares_by_agent_need_both_agents_on_the_target() -> None:
    target, horizon = (5, 5), 20
    passing = [(5, 4), target] * (horizon // 2) + [(5, 4)]  # on the target every other step
    results = _episodes([[target] * (horizon + 1)], [passing], [False])
    shares = failure_decomposition(results, target)
    assert shares["stay_share_more_staying"] == pytest.approx(1.0)  # A waits
    assert shares["stay_share_less_staying"] == pytest.approx(0.0)  # B passes through
    alone = failure_decomposition(
        _episodes([[target] * (horizon + 1)], [[(0, 0)] * 21], [False]), target
    )
    assert alone["stay_on_target_share"] == pytest.approx(1.0)
    assert alone["stay_share_more_staying"] is None and alone["stay_share_less_staying"] is None


def test_mutual_information_of_known_distributions() -> None:
    x = np.repeat([0, 1], 500)
    assert mutual_information(x, x) == pytest.approx(1.0)
    assert mutual_information(x, np.tile([0, 1], 500)) == pytest.approx(0.0, abs=1e-12)
    assert mutual_information(x, np.zeros(1000, dtype=int)) == 0.0


def test_causal_influence_is_zero_for_a_receiver_that_ignores_the_message() -> None:
    states = np.random.default_rng(0).random((50, 11)).astype(np.float32)
    ignores = lambda obs: obs[:, :5]  # noqa: E731
    assert causal_influence(ignores, states, 9, np.array([0.5, 0.5]), 0.05) == 0.0
    follows = lambda obs: np.stack([obs[:, 9], 1 - obs[:, 9], *[0 * obs[:, 9]] * 3], 1)  # noqa: E731
    # two equally likely messages, each picks another action: I = H(a) under ε = 0 -> 1 bit
    assert causal_influence(follows, states, 9, np.array([0.5, 0.5]), 0.0) == pytest.approx(1.0)


def test_arrivals_count_only_the_steps_of_each_episode() -> None:
    target, far = (1, 1), (0, 0)
    # episode 0: A arrives at step 2 and stays, B never; ends at step 4 (time limit)
    # episode 1: B arrives at step 1, A at step 3 (success, length 3); then held on the target
    positions = np.array(
        [
            [[far, far], [far, far], [target, far], [target, far], [target, far]],
            [[far, far], [far, target], [far, target], [target, target], [target, target]],
        ]
    )
    arrived = arrivals(positions, np.array([4, 3]), target)
    assert arrived.reached.tolist() == [[True, False], [True, True]]
    assert arrived.first_arrival.tolist() == [[2, 0], [3, 1]]
    assert arrived.one_never_arrives.tolist() == [True, False]
    assert arrived.both_arrived.tolist() == [False, True]
    assert arrived.steps_one_on_target.tolist() == [3, 2]
    assert not on_target(positions, np.array([4, 2]), target)[1, 3:].any()  # after its end


def test_summary_gives_the_steps_of_the_successful_episodes_only() -> None:
    results = EpisodeResults(
        returns=np.array([9.3, 8.9, -5.0]),
        successes=np.array([True, True, False]),
        lengths=np.array([8, 12, 50]),
    )
    summary = summarize(results)
    assert summary["success_rate"] == pytest.approx(2 / 3)
    assert summary["mean_steps_to_success"] == pytest.approx(10.0)
    assert summary["mean_return"] == pytest.approx(13.2 / 3)


def _pair(success: float, steps: float | None, mean_return: float = 0.0) -> tuple[dict, dict]:
    summary = {"success_rate": success, "mean_steps_to_success": steps, "mean_return": mean_return}
    return summary, summary


def test_selection_by_steps_takes_the_fastest_of_the_nearly_most_successful() -> None:
    candidates = [
        _pair(0.0, None),  # nothing learned yet
        _pair(0.995, 12.0),  # the most successful
        _pair(0.985, 11.0),  # one point less: as good, and faster
        _pair(0.97, 9.0),  # faster still, but 2.5 points less successful
        _pair(0.985, 11.0),  # equal to index 2: the earlier one stays
    ]
    assert select_best(candidates, "steps") == 2
    assert select_best(candidates, "success") == 1
    assert select_best([_pair(0.5, 10.0, 3.0), _pair(0.5, 10.0, 4.0)], "return") == 1
    assert select_best([_pair(0.0, None), _pair(0.0, None)], "steps") == 0
    with pytest.raises(ValueError, match="select_by"):
        select_best(candidates, "luck")


def test_waiting_steps_count_only_steps_alone_on_the_target() -> None:
    target = (8, 1)
    a = [(6, 1), (7, 1), (8, 1), (8, 1), (8, 1), (8, 1)]  # on the target from step 2
    b = [(8, 4), (8, 3), (8, 2), (8, 2), (8, 1), (8, 1)]  # arrives at step 4
    positions = np.stack([np.array(a), np.array(b)], axis=1)  # (L + 1, 2, 2)
    trace = EpisodeTrace(positions=positions, messages=np.zeros((5, 2)), success=True)
    np.testing.assert_array_equal(waiting_steps(trace, target), [2, 0])  # A waits at 2 and 3


def test_measures_are_written_to_12_significant_digits() -> None:
    from analysis.outputs import portable

    data = {"a": [0.017300812567193416, 2], "b": {"c": 1e-17, "d": "text"}}
    assert portable(data) == {"a": [0.0173008125672, 2], "b": {"c": 1e-17, "d": "text"}}
    assert portable(0.23148338125870851) == portable(0.2314833812587085)
