"""The exact joint DP (joint_dp.py) and the reward study's measures (reward_study.py).

Hand-computed values on corridors, a brute force over every joint action sequence on a
small map, and the behaviour measures on hand-made trajectories."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import torch
from analysis.baselines import random_policy
from analysis.episodes import recorded_episodes
from analysis.runs import sha256_of
from analysis.stats import seed_statistics
from batch.plumbing import save_map
from models import AgentDQN, export_policy
from studies import joint_dp, reward_study
from vector_env import VectorMultiAgentEnv, generate_map

GAMMA = 0.99
CORRIDOR_3 = np.array([[0, 2, 0]])  # A | target | B
CORRIDOR_4 = np.array([[2, 0, 0, 0]])  # target | A | . | B


def optimal_value(grid, reward, start_a, start_b, horizon=None, gamma=GAMMA):
    space = joint_dp.build_joint_space(grid)
    transitions = joint_dp.build_transitions(space, reward)
    if horizon is None:
        solution = joint_dp.solve_stationary(transitions, gamma)
    else:
        solution = joint_dp.solve_finite_horizon(transitions, gamma, horizon)
    state = space.state_index(space.cell_index(*start_a), space.cell_index(*start_b), 0, 0)
    return float(joint_dp.optimal_values(solution, np.array([state]))[0])


# By hand, 1×3 corridor, A left and B right of the target, γ = 0.99:
#  H=1: both step on: 10.  H=2: A on (+2), B joins (+10): 2 + 0.99·10 = 11.9 under both.
#  H=3 per_step: 2 + 2γ + 10γ² = 13.781; arrival: A on (+2), A off while B on (+2, B's
#  first arrival), A back (+10): the same 13.781.
#  H=4 per_step: 2 + 2γ + 2γ² + 10γ³ = 15.64319; arrival cannot earn a third bonus: 13.781.
#  No clock (stationary): per_step parks forever, 2 / (1 − γ) = 200; arrival stays 13.781.
@pytest.mark.parametrize(
    ("reward", "horizon", "expected"),
    [
        ("per_step", 1, 10.0),
        ("arrival", 1, 10.0),
        ("per_step", 2, 11.9),
        ("arrival", 2, 11.9),
        ("per_step", 3, 13.781),
        ("arrival", 3, 13.781),
        ("per_step", 4, 15.64319),
        ("arrival", 4, 13.781),
        ("per_step", None, 200.0),
        ("arrival", None, 13.781),
    ],
)
def test_corridor_of_three_values_by_hand(reward, horizon, expected):
    value = optimal_value(CORRIDOR_3, reward, (0, 0), (0, 2), horizon)
    assert value == pytest.approx(expected, abs=1e-6)
    swapped = optimal_value(CORRIDOR_3, reward, (0, 2), (0, 0), horizon)
    assert swapped == pytest.approx(expected, abs=1e-6)


# By hand, 1×4 corridor, A next to the target, B three cells away, H = 3:
#  per_step: A on (+2), A stays while B walks (+2), B on (+10): 2 + 1.98 + 9.801 = 13.781.
#  arrival: A on (+2), a step without bonus (−0.1), B on (+10): 2 − 0.099 + 9.801 = 11.702.
@pytest.mark.parametrize(("reward", "expected"), [("per_step", 13.781), ("arrival", 11.702)])
def test_corridor_of_four_values_by_hand(reward, expected):
    assert optimal_value(CORRIDOR_4, reward, (0, 1), (0, 3), 3) == pytest.approx(expected)


def literal_reward(reward, on_a, on_b, visited_a, visited_b):
    """The contract's wording, independently of joint_dp.team_reward."""
    if on_a and on_b:
        return 10.0, True
    if reward == "per_step":
        return (2.0 if on_a or on_b else -0.1), False
    first = (on_a and not visited_a) or (on_b and not visited_b)
    return (2.0 if first else -0.1), False


def move(grid, cell, action):
    row, col = cell[0] + [-1, 1, 0, 0, 0][action], cell[1] + [0, 0, -1, 1, 0][action]
    inside = 0 <= row < grid.shape[0] and 0 <= col < grid.shape[1]
    return (row, col) if inside and grid[row, col] != 1 else cell


def brute_force_value(grid, reward, start_a, start_b, horizon, gamma=GAMMA):
    """Best discounted return over all 25^horizon joint action sequences."""
    target = tuple(np.argwhere(grid == 2)[0])
    best = -np.inf
    for sequence in itertools.product(range(25), repeat=horizon):
        a, b, visited_a, visited_b, total = start_a, start_b, False, False, 0.0
        for t, joint in enumerate(sequence):
            a, b = move(grid, a, joint // 5), move(grid, b, joint % 5)
            on_a, on_b = a == target, b == target
            reward_t, done = literal_reward(reward, on_a, on_b, visited_a, visited_b)
            total += gamma**t * reward_t
            visited_a, visited_b = visited_a or on_a, visited_b or on_b
            if done:
                break
        best = max(best, total)
    return best


@pytest.mark.parametrize("reward", joint_dp.REWARDS)
def test_dp_matches_brute_force_on_a_small_map(reward):
    grid = np.array([[0, 0, 1], [2, 0, 0]])
    horizon = 3
    space = joint_dp.build_joint_space(grid)
    transitions = joint_dp.build_transitions(space, reward)
    solution = joint_dp.solve_finite_horizon(transitions, GAMMA, horizon)
    starts = space.start_states()
    assert len(starts) == 4 * 3  # ordered pairs of distinct free non-target cells
    values = joint_dp.optimal_values(solution, starts)
    cell_a, cell_b, _, _ = space.decode(starts)
    for value, a, b in zip(values, cell_a, cell_b, strict=True):
        start_a, start_b = tuple(space.cells[a]), tuple(space.cells[b])
        assert value == pytest.approx(brute_force_value(grid, reward, start_a, start_b, horizon))


@pytest.mark.parametrize("reward", joint_dp.REWARDS)
def test_greedy_rollout_earns_the_optimal_value(reward):
    """Re-scoring the greedy roll-out from its positions gives back V*(start)."""
    grid = generate_map((5, 5), 3)
    space = joint_dp.build_joint_space(grid)
    transitions = joint_dp.build_transitions(space, reward)
    solution = joint_dp.solve_finite_horizon(transitions, GAMMA, 20)
    starts = space.start_states()
    episodes = joint_dp.roll_out(space, transitions, solution, starts, 20)
    target = tuple(space.cells[space.target])
    rescored = joint_dp.returns_from_positions(
        episodes.positions, episodes.lengths, target, reward, GAMMA
    )
    np.testing.assert_allclose(rescored, joint_dp.optimal_values(solution, starts), atol=1e-9)
    assert episodes.successes.all()  # 20 steps suffice on a 5×5 map under both rewards


def test_stationary_solution_is_the_limit_of_long_horizons():
    space = joint_dp.build_joint_space(CORRIDOR_4)
    transitions = joint_dp.build_transitions(space, "arrival")
    stationary = joint_dp.solve_stationary(transitions, GAMMA)
    long = joint_dp.solve_finite_horizon(transitions, GAMMA, 3000)
    np.testing.assert_allclose(stationary.values[0], long.values[0], atol=1e-7)


def test_potential_shaping_shifts_values_by_the_potential_only():
    """Corridor of four: distance potential -(d_A + d_B); with it the stationary optimum of
    the assignment's reward still parks (value 2/(1-γ) - 0.1 for the walk, minus Φ)."""
    space = joint_dp.build_joint_space(CORRIDOR_4)
    transitions = joint_dp.build_transitions(space, "per_step")
    potential = joint_dp.distance_potential(space, scale=2.0)
    start = space.state_index(space.cell_index(0, 1), space.cell_index(0, 3), 0, 0)
    assert potential[start] == -2.0 * (1 + 3)
    plain = joint_dp.solve_stationary(transitions, GAMMA)
    shaped = joint_dp.solve_stationary(
        joint_dp.with_potential_shaping(transitions, potential, GAMMA), GAMMA
    )
    np.testing.assert_allclose(shaped.values[0], plain.values[0] - potential, atol=1e-6)
    assert plain.values[0, start] == pytest.approx(200.0)  # A parks at once, B stays away
    episodes = joint_dp.roll_out(space, transitions, shaped, np.array([start]), 50)
    assert not episodes.successes[0]


def test_returns_from_positions_by_hand():
    # 1×4 corridor, target at (0, 0): A arrives at step 1 and stays; B arrives at step 3.
    a = [(0, 1), (0, 0), (0, 0), (0, 0)]
    b = [(0, 3), (0, 2), (0, 1), (0, 0)]
    positions = np.array([list(zip(a, b, strict=True))])  # (1, 4, 2, 2)
    lengths = np.array([3])
    per_step = joint_dp.returns_from_positions(positions, lengths, (0, 0), "per_step")
    arrival = joint_dp.returns_from_positions(positions, lengths, (0, 0), "arrival")
    assert per_step[0] == pytest.approx(2 + 2 + 10)
    assert arrival[0] == pytest.approx(2 - 0.1 + 10)
    # The same episode cut at step 2 (truncated): no +10.
    short = joint_dp.returns_from_positions(positions, np.array([2]), (0, 0), "per_step")
    assert short[0] == pytest.approx(4.0)


@pytest.mark.parametrize("reward", joint_dp.REWARDS)
def test_rewards_and_moves_agree_with_the_environment(reward):
    """Random episodes on map 641: the env's returns equal the ones re-computed from the
    recorded positions, and the DP's move table reproduces every recorded move."""
    env = VectorMultiAgentEnv(200, seed=641, reward_mode=reward)
    results = recorded_episodes(env, random_policy(seed=5), 400, seed=11)
    positions, actions = results.trajectories["positions"], results.trajectories["actions"]
    recomputed = joint_dp.returns_from_positions(
        positions, results.lengths, env.target_position, reward
    )
    np.testing.assert_allclose(recomputed, results.returns, atol=1e-4)  # env sums float32
    space = joint_dp.build_joint_space(env.grid)
    index = np.full(env.grid.shape, -1)
    index[space.cells[:, 0], space.cells[:, 1]] = np.arange(space.num_cells)
    taken = actions >= 0  # (E, T, 2); -1 after the end
    before = index[positions[:, :-1, :, 0], positions[:, :-1, :, 1]]
    after = index[positions[:, 1:, :, 0], positions[:, 1:, :, 1]]
    np.testing.assert_array_equal(space.next_cell[before[taken], actions[taken]], after[taken])


def test_bad_reward_name_is_refused():
    with pytest.raises(ValueError, match="reward must be one of"):
        joint_dp.team_reward("literal", np.zeros(2, bool), np.zeros(2, bool))


# --------------------------------------------------------------------- reward_study measures
OPEN_3X3 = np.array([[0, 0, 0], [0, 2, 0], [0, 0, 0]])


def test_behaviour_measures_on_hand_made_episodes():
    # Episode 1 (3 steps, failed): A steps on the target and stays; B comes next to it at
    # step 1 and walks away at step 2. Episode 2: A arrives at step 1, B at step 2.
    a1, b1 = [(1, 0), (1, 1), (1, 1), (1, 1)], [(0, 0), (0, 1), (0, 0), (0, 0)]
    a2, b2 = [(1, 0), (1, 1), (1, 1), (1, 1)], [(0, 1), (0, 1), (1, 1), (1, 1)]
    positions = np.array(
        [list(zip(a1, b1, strict=True)), list(zip(a2, b2, strict=True))]
    )  # (2, 4, 2, 2)
    measures = reward_study.episode_measures(
        positions, np.array([3, 2]), np.array([False, True]), OPEN_3X3
    )
    assert measures == pytest.approx(
        {
            "success_rate": 0.5,
            "mean_steps_to_success": 2.0,
            "return_assignment": ((2 + 2 + 2) + (2 + 10)) / 2,
            "return_arrival": ((2 - 0.1 - 0.1) + (2 + 10)) / 2,
            "one_never_arrives": 0.5,
            "second_agent_reaches_target": 0.5,
            "turned_away": 0.5,
            "time_between_arrivals": 1.0,
            "steps_one_on_target": (3 + 1) / 2,
        }
    )
    assert set(measures) == set(reward_study.MEASURES)


def test_hovering_next_to_the_target_is_not_turning_away():
    a = [(1, 0), (1, 1), (1, 1), (1, 1)]
    b = [(0, 0), (0, 1), (0, 1), (0, 1)]  # comes next to the target and waits there
    positions = np.array([list(zip(a, b, strict=True))])
    measures = reward_study.episode_measures(positions, np.array([3]), np.array([False]), OPEN_3X3)
    assert measures["turned_away"] == 0.0
    assert measures["one_never_arrives"] == 1.0
    assert measures["time_between_arrivals"] is None


def synthetic_learned(literal_return, literal_success, arrival_return, arrival_success):
    def batch(returns, successes):
        row = {
            "return_assignment": seed_statistics(returns),
            "success_rate": seed_statistics(successes),
        }
        return {"full": {"greedy": row, "epsilon": row}}

    return {
        "per_step": batch(literal_return, literal_success),
        "arrival": batch(arrival_return, arrival_success),
    }


def test_verdict_names_a_misspecified_reward_only_when_both_conditions_hold():
    hacked = reward_study.verdicts(synthetic_learned([40, 50], [0.0, 0.1], [10, 12], [0.8, 0.9]))
    assert hacked["full"]["greedy"]["literal_reward_misspecified"]
    assert hacked["full"]["greedy"]["return_assignment"]["ci95_separated"]
    assert hacked["all_cases_misspecified"] and hacked["cases_misspecified"] == 2
    weak = reward_study.verdicts(synthetic_learned([5, 6], [0.0, 0.1], [10, 12], [0.8, 0.9]))
    assert weak["full"]["greedy"]["literal_succeeds_less"]
    assert not weak["full"]["greedy"]["literal_reward_misspecified"]
    assert not weak["all_cases_misspecified"] and weak["cases_misspecified"] == 0


def write_batch(folder, reward_mode, grid):
    torch.manual_seed(0)
    for seed in (1, 2):
        for agent in "AB":
            export_policy(AgentDQN(), "full", folder / f"full_seed{seed}_agent_{agent}.pt")
    (folder / "hyperparameters.json").write_text(
        json.dumps({"reward_mode": reward_mode, "max_steps": 50}), encoding="utf-8"
    )
    save_map(folder / "map.json", grid)


def strict_json(path):
    def refuse(constant):
        raise ValueError(f"non-finite number {constant} in {path}")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse)


def test_study_end_to_end_on_untrained_agents(tmp_path, capsys):
    grid = generate_map((10, 10), 641)
    write_batch(tmp_path / "per_step", "per_step", grid)
    write_batch(tmp_path / "arrival", "arrival", grid)
    argv = ["--per_step_models", str(tmp_path / "per_step"), "--arrival_models"]
    argv += [str(tmp_path / "arrival"), "--output_dir", str(tmp_path / "out")]
    reward_study.main([*argv, "--num_episodes", "20"])
    study = strict_json(tmp_path / "out" / "reward_study.json")
    assert (tmp_path / "out" / "reward_study.png").stat().st_size > 0
    dp = study["exact_dp"]
    assert dp["finite_horizon"]["arrival"]["success_rate"] == 1.0
    assert dp["stationary"]["per_step"]["success_rate"] == 0.0  # without a clock it parks
    assert dp["finite_horizon"]["per_step"]["mean_steps_to_success"] == 50.0  # joins last
    assert study["shaping_check"]["shaped_optimum"]["success_rate"] == 0.0
    learned = study["learned"]["per_step"]["full"]
    assert learned["seeds"] == [1, 2]
    assert len(learned["greedy"]["success_rate"]["per_seed"]) == 2
    assert set(study["verdict"]) == {
        "full",
        "all_cases_misspecified",
        "cases_misspecified",
        "cases",
    }
    assert "exact DP" in capsys.readouterr().out


def test_study_refuses_a_batch_trained_on_the_other_reward(tmp_path):
    grid = generate_map((10, 10), 641)
    write_batch(tmp_path / "a", "arrival", grid)
    argv = ["--per_step_models", str(tmp_path / "a"), "--arrival_models", str(tmp_path / "a")]
    with pytest.raises(ValueError, match="trained with reward 'arrival', not 'per_step'"):
        reward_study.main([*argv, "--output_dir", str(tmp_path / "out"), "--num_episodes", "5"])


def test_a_batch_manifest_decides_runs_and_settings(tmp_path):
    grid = generate_map((10, 10), 641)
    write_batch(tmp_path, "arrival", grid)  # files of seeds 1 and 2
    for agent in "AB":  # the manifest lists seed 2 only: seed 1 is another batch's
        (tmp_path / f"full_seed1_agent_{agent}.pt").unlink()
    models = {agent: f"full_seed2_agent_{agent}.pt" for agent in "AB"}
    digests = {agent: sha256_of(tmp_path / name) for agent, name in models.items()}
    run = {"mode": "full", "seed": 2, "models": models, "sha256": digests, "selection": {}}
    manifest = {"format": 1, "reward_mode": "per_step", "hyperparameters": {"max_steps": 50}}
    manifest["runs"] = {"full_seed2": run}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    batch = reward_study.open_batch(tmp_path, "per_step", grid, 50)  # not hyperparameters.json
    assert batch.seeds == {"full": [2]}
    with pytest.raises(ValueError, match="trained with reward 'per_step', not 'arrival'"):
        reward_study.open_batch(tmp_path, "arrival", grid, 50)
    with pytest.raises(ValueError, match="max_steps"):
        reward_study.open_batch(tmp_path, "per_step", grid, 40)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--dp_only", "--num_episodes", "0"], "--num_episodes must be a positive integer"),
        (["--dp_only", "--epsilon", "1.5"], "--epsilon must lie in"),
        (["--dp_only", "--gamma", "1"], "--gamma must lie in"),
        (["--per_step_models", "no/such/folder"], "--per_step_models: folder"),
    ],
)
def test_bad_arguments_are_usage_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        reward_study.parse_args(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
