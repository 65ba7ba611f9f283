"""Transition model and sampled dynamics of the gridworld."""

from __future__ import annotations

import math

import numpy as np
import pytest
from environment import DOWN, LEFT, RIGHT, UP, GridWorldEnv
from tabular_model import TabularModel

OPEN_CELL = (2, 3)  # all four neighbours free: the three outcomes are distinct cells


@pytest.fixture()
def env() -> GridWorldEnv:
    return GridWorldEnv(seed=1)


def test_probabilities_sum_to_one_everywhere(env: GridWorldEnv) -> None:
    for state in range(25):
        for action in range(4):
            probs = env.get_transition_prob(state, action)
            assert math.isclose(sum(probs.values()), 1.0)
            assert all(p > 0 for p in probs.values())


@pytest.mark.parametrize(
    ("action", "intended", "left", "right"),
    [
        (UP, (1, 3), (2, 2), (2, 4)),
        (RIGHT, (2, 4), (1, 3), (3, 3)),
        (DOWN, (3, 3), (2, 4), (2, 2)),
        (LEFT, (2, 2), (3, 3), (1, 3)),
    ],
)
def test_drift_goes_to_the_two_perpendicular_sides(env, action, intended, left, right) -> None:
    outcomes = env._get_next_positions(OPEN_CELL, action)
    assert outcomes == env.outcomes(OPEN_CELL, action)  # three distinct cells: nothing merged
    assert outcomes == [(intended, 0.8), (left, pytest.approx(0.1)), (right, pytest.approx(0.1))]
    for pos, _ in outcomes[1:]:
        delta = (pos[0] - OPEN_CELL[0], pos[1] - OPEN_CELL[1])
        intended_delta = (intended[0] - OPEN_CELL[0], intended[1] - OPEN_CELL[1])
        assert delta[0] * intended_delta[0] + delta[1] * intended_delta[1] == 0


def test_walls_keep_the_agent_in_place(env: GridWorldEnv) -> None:
    # From the top-left corner, UP hits the wall and its left drift (LEFT) hits the wall too.
    assert env._get_next_positions((0, 0), UP) == [((0, 0), 0.9), ((0, 1), 0.1)]
    assert env.outcomes((0, 0), UP) == [((0, 0), 0.8), ((0, 0), 0.1), ((0, 1), 0.1)]
    assert env.get_transition_prob(0, UP) == {0: pytest.approx(0.9), 1: pytest.approx(0.1)}
    assert env.get_transition_prob(0, LEFT) == {0: pytest.approx(0.9), 5: pytest.approx(0.1)}


def test_obstacles_keep_the_agent_in_place(env: GridWorldEnv) -> None:
    # (1, 1): RIGHT leads into the obstacle (1, 2), DOWN into the obstacle (2, 1).
    state = env._pos_to_state((1, 1))
    assert env.get_transition_prob(state, RIGHT) == {
        state: pytest.approx(0.8 + 0.1),
        env._pos_to_state((0, 1)): pytest.approx(0.1),
    }
    assert not env._is_valid_pos((1, 2)) and not env._is_valid_pos((5, 0))
    assert not env._is_valid_pos((-1, 0)) and env._is_valid_pos((0, 0))


def test_rewards_depend_on_the_cell_entered(env: GridWorldEnv) -> None:
    assert env._calculate_reward((4, 4)) == 10.0
    assert env._calculate_reward((3, 3)) == -5.0 and env._calculate_reward((3, 0)) == -5.0
    assert env._calculate_reward((0, 1)) == -0.1
    # Bumping a wall while standing on a penalty cell enters it again.
    penalty = env._pos_to_state((3, 0))
    assert env.get_reward(penalty, LEFT, penalty) == -5.0


def test_step_samples_outcomes_with_the_right_frequencies() -> None:
    """20 000 draws from a cell with three distinct outcomes. Each observed frequency must lie
    within 4.5 standard errors of its probability (a false alarm has odds below 1e-5)."""
    env = GridWorldEnv(seed=123)
    draws = 20_000
    counts = {"intended": 0, "drift_left": 0, "drift_right": 0}
    for _ in range(draws):
        env.reset()
        env.current_pos = OPEN_CELL
        _, _, _, info = env.step(UP)
        counts[info["outcome"]] += 1
    for outcome, p in (("intended", 0.8), ("drift_left", 0.1), ("drift_right", 0.1)):
        standard_error = math.sqrt(p * (1 - p) / draws)
        assert abs(counts[outcome] / draws - p) < 4.5 * standard_error, counts


def test_step_positions_follow_the_sampled_outcome() -> None:
    env = GridWorldEnv(seed=7)
    expected = dict(
        zip(
            ("intended", "drift_left", "drift_right"),
            [pos for pos, _ in env.outcomes(OPEN_CELL, DOWN)],
            strict=True,
        )
    )
    for _ in range(200):
        env.reset()
        env.current_pos = OPEN_CELL
        state, _, _, info = env.step(DOWN)
        assert env._state_to_pos(state) == expected[info["outcome"]] == info["position"]


def test_episode_ends_at_the_goal_with_its_reward() -> None:
    env = GridWorldEnv(prob_drift=0.0)
    env.reset()
    rewards = [env.step(a)[1] for a in (RIGHT, RIGHT, RIGHT, RIGHT, DOWN, DOWN, DOWN)]
    assert rewards == [-0.1] * 7 and not env.done
    state, reward, done, info = env.step(DOWN)
    assert (state, reward, done, info["truncated"]) == (24, 10.0, True, False)


def test_episode_is_cut_after_fifty_steps() -> None:
    env = GridWorldEnv(prob_drift=0.0)
    env.reset()
    for step in range(1, 51):
        _, reward, done, info = env.step(UP)  # into the wall: the agent never moves
        assert reward == -0.1
        assert done == (step == 50)
    assert info["truncated"] and info["steps"] == 50
    with pytest.raises(ValueError, match="episode ended"):
        env.step(UP)
    assert env.reset() == 0 and env.step(RIGHT)[0] == 1


def test_penalty_cell_does_not_end_the_episode() -> None:
    env = GridWorldEnv(prob_drift=0.0)
    env.reset()
    env.current_pos = (2, 0)
    state, reward, done, _ = env.step(DOWN)
    assert (env._state_to_pos(state), reward, done) == ((3, 0), -5.0, False)
    assert env.step(LEFT)[1:3] == (-5.0, False)  # wall bump on the penalty cell


def test_same_seed_gives_the_same_trajectory() -> None:
    def trajectory(seed: int) -> list[int]:
        env = GridWorldEnv(seed=seed)
        env.reset()
        return [env.step(RIGHT if t % 2 else DOWN)[0] for t in range(30) if not env.done]

    assert trajectory(5) == trajectory(5)
    assert any(trajectory(5) != trajectory(s) for s in range(6, 10))


def test_tabular_model_matches_get_transition_prob(env: GridWorldEnv) -> None:
    model = TabularModel.from_env(env)
    for state in range(25):
        for action in range(4):
            merged: dict[int, float] = {}
            for s, p in zip(
                model.next_states[state, action], model.probs[state, action], strict=True
            ):
                merged[int(s)] = merged.get(int(s), 0.0) + float(p)
            assert merged == pytest.approx(env.get_transition_prob(state, action))
            rewards = [
                env.get_reward(state, action, int(s)) for s in model.next_states[state, action]
            ]
            assert model.rewards[state, action].tolist() == rewards
    assert np.flatnonzero(model.terminal).tolist() == [24]
    assert np.flatnonzero(model.absorbing).tolist() == [7, 11, 24]
