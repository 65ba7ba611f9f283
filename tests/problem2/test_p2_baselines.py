"""Baseline policies and the shared episode loop."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from analysis.baselines import (
    MAP_SEEDS,
    ON_TARGET_MESSAGE,
    PERPENDICULAR,
    POLICIES,
    beacon_explorer_policy,
    evaluate_baselines,
    main,
    random_policy,
    summary,
)
from analysis.episodes import (
    oracle_policy,
    recorded_episodes,
    shortest_path_actions,
    target_distances,
)
from rollout import evaluate_policy, run_episodes
from vector_env import ACTION_DELTAS, VectorMultiAgentEnv, generate_map


@pytest.mark.parametrize("map_seed", MAP_SEEDS)
def test_oracle_always_succeeds_along_shortest_paths(map_seed: int) -> None:
    grid = generate_map((10, 10), map_seed)
    env = VectorMultiAgentEnv(200, grid=grid)
    results = recorded_episodes(env, oracle_policy(grid), 200, seed=1)
    assert results.successes.all()
    distances = target_distances(grid)
    start = results.trajectories["positions"][:, 0]
    farther = np.maximum(
        distances[start[:, 0, 0], start[:, 0, 1]], distances[start[:, 1, 0], start[:, 1, 1]]
    )
    assert np.array_equal(results.lengths, farther)  # the slower agent sets the pace
    assert (results.lengths <= 50).all()


def test_random_policy_rarely_succeeds() -> None:
    grid = generate_map((10, 10), 641)
    summary = evaluate_policy(VectorMultiAgentEnv(1000, grid=grid), random_policy(0), 1000, 0)
    assert summary["episodes"] == 1000
    assert summary["success_rate"] < 0.05
    assert summary["mean_return"] < 0


def test_shortest_path_actions_move_one_step_closer() -> None:
    grid = generate_map((10, 10), 3)
    distances = target_distances(grid)
    actions = shortest_path_actions(grid)
    for row, col in np.argwhere(distances > 0):
        d_row, d_col = ACTION_DELTAS[actions[row, col]]
        assert distances[row + d_row, col + d_col] == distances[row, col] - 1
    assert actions[tuple(np.argwhere(grid == 2)[0])] == 4  # Stay on the target


def test_episode_loop_is_reproducible_and_counts_exactly() -> None:
    env = VectorMultiAgentEnv(10, seed=641)
    first = recorded_episodes(env, random_policy(5), 25, seed=3)
    again = recorded_episodes(env, random_policy(5), 25, seed=3)
    assert len(first.returns) == 25  # three rounds of ten, the last one cut
    assert np.array_equal(first.returns, again.returns)
    assert np.array_equal(first.trajectories["positions"], again.trajectories["positions"])
    assert (first.lengths >= 1).all() and (first.lengths <= 50).all()


def test_recorded_trajectories_are_consistent() -> None:
    grid = generate_map((10, 10), 0)
    env = VectorMultiAgentEnv(20, grid=grid)
    results = recorded_episodes(env, random_policy(1), 20, seed=0)
    log = results.trajectories
    assert log["positions"].shape == (20, 51, 2, 2)
    assert log["observations"].shape == (20, 51, 2, 11)
    for episode, length in enumerate(results.lengths):
        assert (log["actions"][episode, :length] >= 0).all()
        assert (log["actions"][episode, length:] == -1).all()
        assert np.isnan(log["messages"][episode, length:]).all()
        assert log["rewards"][episode].sum() == pytest.approx(results.returns[episode], abs=1e-4)
        steps = np.abs(np.diff(log["positions"][episode, : length + 1], axis=0)).sum(axis=-1)
        assert (steps <= 1).all()
        received = log["observations"][episode, 1 : length + 1, :, 9]
        assert np.allclose(received, log["messages"][episode, :length, ::-1])


def test_episode_loop_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="auto_reset"):
        run_episodes(VectorMultiAgentEnv(2, auto_reset=False), random_policy(0), 2)
    with pytest.raises(ValueError, match="num_episodes"):
        run_episodes(VectorMultiAgentEnv(2), random_policy(0), 0)


def test_baseline_script_writes_json(tmp_path: Path, monkeypatch, capsys) -> None:
    output = tmp_path / "evaluation_results" / "baselines.json"
    monkeypatch.setattr(sys, "argv", ["baselines.py", "--episodes", "30", "--output", str(output)])
    main()
    results = json.loads(output.read_text(encoding="utf-8"))
    assert set(results["maps"]) == {str(seed) for seed in MAP_SEEDS}
    assert set(results["maps"]["641"]) >= set(POLICIES)
    for entry in results["maps"].values():
        assert entry["oracle"]["success_rate"] == 1.0
        assert set(entry["random"]) >= {"success_rate", "mean_return_arrival"}
        assert np.array(entry["grid"]).shape == (10, 10)
    assert "oracle" in capsys.readouterr().out


def test_summary_names_every_policy_on_one_line() -> None:
    results = evaluate_baselines(num_episodes=20, map_seeds=(641, 0))
    line = summary(results)
    assert "\n" not in line and "2 maps" in line and "map 641" in line
    assert all(name in line for name in POLICIES)
    line.encode("cp1252")  # a Windows console shows it as it is
    assert results["maps"]["641"]["target"] == list(
        map(int, np.argwhere(generate_map((10, 10), 641) == 2)[0])
    )


def _open_observation(n: int, message: float, distance: float, centre: int = 0) -> np.ndarray:
    """Observations (n, 2, 11) of two agents on open cells: free 3 x 3 patch (``centre`` in
    the middle), the partner's ``message`` and the ``distance``."""
    obs = np.zeros((n, 2, 11), dtype=np.float32)
    obs[..., 4] = centre
    obs[..., 9], obs[..., 10] = message, distance
    return obs


def test_beacon_explorer_says_on_target_and_stays() -> None:
    policy = beacon_explorer_policy(seed=0)
    obs = _open_observation(4, 0.0, 0.3)
    obs[:2, 0, 4] = 2  # agent A of the first two copies stands on the target
    actions, messages = policy(obs, np.zeros((4, 2, 2), dtype=np.int64))
    assert np.array_equal(messages[:, 0], [ON_TARGET_MESSAGE, ON_TARGET_MESSAGE, 0.0, 0.0])
    assert (messages[:, 1] == 0).all() and (actions[:2, 0] == 4).all()  # Stay on the target


def test_beacon_explorer_turns_across_when_the_partners_distance_grows() -> None:
    policy = beacon_explorer_policy(seed=3)
    positions = np.zeros((200, 2, 2), dtype=np.int64)
    first, _ = policy(_open_observation(200, 1.0, 0.30), positions)
    closer, _ = policy(_open_observation(200, 1.0, 0.25), positions)
    assert np.array_equal(closer, first)  # getting closer: keep the heading
    farther, _ = policy(_open_observation(200, 1.0, 0.35), positions)
    assert all(farther[k, a] in PERPENDICULAR[closer[k, a]] for k in range(200) for a in (0, 1))
    unheard, _ = policy(_open_observation(200, 0.0, 0.50), positions)
    assert np.array_equal(unheard, farther)  # no beacon: the distance is not used


def test_beacon_explorer_finds_a_parked_partner_more_often_than_the_sweep() -> None:
    """With the partner already on the target, the beacon is all that differs."""
    grid = generate_map((10, 10), 641)
    target = np.argwhere(grid == 2)[0]
    env = VectorMultiAgentEnv(400, grid=grid)
    starts = start_positions_with_b_on(env, target, seed=2)
    rates = {}
    for name in ("sweep_explorer", "beacon_explorer"):
        run = run_episodes(env, POLICIES[name](grid, 5), 400, start_positions=starts)
        rates[name] = run.successes.mean()
    assert rates["beacon_explorer"] > rates["sweep_explorer"] + 0.1


def start_positions_with_b_on(
    env: VectorMultiAgentEnv, target: np.ndarray, seed: int
) -> np.ndarray:
    """Start cells (N, 2, 2): A on a random free cell, B on the target."""
    env.reset(seed=seed)
    starts = env.positions.copy()
    starts[:, 1] = target
    return starts
