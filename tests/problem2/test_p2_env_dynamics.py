"""Dynamics, observations and rewards on hand-built maps, step by step."""

from __future__ import annotations

import math

import numpy as np
import pytest
from multi_agent_env import MultiAgentEnv
from vector_env import VectorMultiAgentEnv

# 5×5: an obstacle at (1, 1), the target at (3, 3).
GRID = np.array(
    [
        [0, 0, 0, 0, 0],
        [0, 1, 0, 0, 0],
        [0, 0, 0, 0, 0],
        [0, 0, 0, 2, 0],
        [0, 0, 0, 0, 0],
    ]
)
UP, DOWN, LEFT, RIGHT, STAY = range(5)


def make_env(position_a, position_b, **kwargs) -> MultiAgentEnv:
    env = MultiAgentEnv(grid=GRID, **kwargs)
    env.reset(positions=[position_a, position_b])
    return env


@pytest.mark.parametrize(
    ("action", "expected"),
    [(UP, (1, 2)), (DOWN, (3, 2)), (LEFT, (2, 1)), (RIGHT, (2, 3)), (STAY, (2, 2))],
)
def test_each_action_moves_one_cell(action: int, expected: tuple[int, int]) -> None:
    env = make_env((2, 2), (4, 0))
    env.step(action, STAY, 0.0, 0.0)
    assert env.agent_positions == [expected, (4, 0)]
    assert env._apply_action((2, 2), action) == expected


@pytest.mark.parametrize(
    ("start", "action"),
    [((0, 0), UP), ((0, 0), LEFT), ((4, 4), DOWN), ((4, 4), RIGHT), ((0, 4), UP), ((4, 0), LEFT)],
)
def test_walls_leave_agent_in_place(start: tuple[int, int], action: int) -> None:
    env = make_env(start, (2, 2))
    env.step(action, STAY, 0.0, 0.0)
    assert env.agent_positions[0] == start


@pytest.mark.parametrize(("start", "action"), [((1, 0), RIGHT), ((0, 1), DOWN), ((2, 1), UP)])
def test_obstacles_block_moves(start: tuple[int, int], action: int) -> None:
    env = make_env((2, 2), start)
    env.step(STAY, action, 0.0, 0.0)
    assert env.agent_positions[1] == start
    assert env._apply_action(start, action) == start


def test_agents_may_share_a_cell() -> None:
    env = make_env((2, 2), (2, 3))
    env.step(STAY, LEFT, 0.0, 0.0)
    assert env.agent_positions == [(2, 2), (2, 2)]


def test_corner_patch_marks_off_grid_cells() -> None:
    env = make_env((0, 0), (4, 4))
    obs_a = env._get_observation(0)
    assert obs_a[:9].tolist() == [-1, -1, -1, -1, 0, 0, -1, 0, 1]


def test_patch_shows_target_and_obstacle_row_major() -> None:
    env = make_env((2, 2), (2, 3))  # B is next to A but agents are not drawn
    obs_a = env._get_observation(0)
    assert obs_a[:9].tolist() == [1, 0, 0, 0, 0, 0, 0, 0, 2]
    env = make_env((3, 3), (0, 0))  # standing on the target
    assert env._get_observation(0)[4] == 2


def test_distance_is_normalised_by_the_diagonal() -> None:
    env = make_env((0, 0), (3, 4))
    obs_a, obs_b = env._get_observation(0), env._get_observation(1)
    assert obs_a[10] == obs_b[10] == pytest.approx(5 / math.sqrt(50))
    env.step(DOWN, STAY, 0.0, 0.0)
    assert env._get_observation(0)[10] == pytest.approx(math.hypot(2, 4) / math.sqrt(50))
    assert make_env((2, 2), (2, 2))._get_observation(0)[10] == 0.0


def test_rectangular_grid_distance_and_walls() -> None:
    grid = np.zeros((3, 6), dtype=int)
    grid[1, 4] = 2
    env = MultiAgentEnv(grid=grid)
    assert env.grid_size == (3, 6)
    env.reset(positions=[(0, 0), (2, 5)])
    assert env._get_observation(0)[10] == pytest.approx(math.hypot(2, 5) / math.hypot(3, 6))
    env.step(DOWN, RIGHT, 0.0, 0.0)
    assert env.agent_positions == [(1, 0), (2, 5)]


def test_messages_reach_the_partner_one_step_later() -> None:
    env = make_env((0, 0), (4, 4))
    obs_a, obs_b = env._get_observation(0), env._get_observation(1)
    assert obs_a[9] == obs_b[9] == 0.0
    (obs_a, obs_b), _, _ = env.step(STAY, STAY, 0.2, 0.9)
    assert obs_a[9] == pytest.approx(0.9) and obs_b[9] == pytest.approx(0.2)
    (obs_a, obs_b), _, _ = env.step(STAY, STAY, 1.0, 0.0)
    assert obs_a[9] == 0.0 and obs_b[9] == 1.0
    obs_a, obs_b = env.reset()
    assert obs_a[9] == obs_b[9] == 0.0


def test_vector_env_delivers_messages_per_copy() -> None:
    env = VectorMultiAgentEnv(3, grid=GRID)
    env.reset(positions=np.array([[[0, 0], [4, 4]]] * 3))
    sent = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    obs, *_ = env.step(np.full((3, 2), STAY), sent)
    assert np.allclose(obs[:, 0, 9], sent[:, 1]) and np.allclose(obs[:, 1, 9], sent[:, 0])


def run(env: MultiAgentEnv, joint_actions: list[tuple[int, int]]) -> list[tuple[float, bool]]:
    return [env.step(a, b, 0.0, 0.0)[1:] for a, b in joint_actions]


# A starts left of the target, B two cells further left. A arrives, waits, leaves, comes
# back, then B walks in. Rewards per reading, step by step.
ARRIVE_LEAVE_RETURN = [
    (RIGHT, STAY),
    (STAY, RIGHT),
    (LEFT, STAY),
    (RIGHT, STAY),
    (STAY, RIGHT),
    (STAY, RIGHT),
]
EXPECTED = {
    "arrival": [2.0, -0.1, -0.1, -0.1, -0.1, 10.0],
    "per_step": [2.0, 2.0, -0.1, 2.0, 2.0, 10.0],
    "goal": [-0.1, -0.1, -0.1, -0.1, -0.1, 10.0],
}


@pytest.mark.parametrize("mode", ["arrival", "per_step", "goal"])
def test_reward_first_arrival_leaving_returning_and_both(mode: str) -> None:
    env = make_env((3, 2), (3, 0), reward_mode=mode)
    outcomes = run(env, ARRIVE_LEAVE_RETURN)
    assert [r for r, _ in outcomes] == EXPECTED[mode]  # exact: one team value per step
    assert [d for _, d in outcomes] == [False] * 5 + [True]
    assert outcomes[-1][0] == 10.0  # exactly +10, no arrival bonus on top
    with pytest.raises(ValueError, match="reset"):
        env.step(STAY, STAY, 0.0, 0.0)


@pytest.mark.parametrize("mode", ["arrival", "per_step"])
def test_second_agent_arrival_pays_its_own_bonus(mode: str) -> None:
    # A arrives and leaves; then B arrives alone (its first arrival); then A rejoins.
    env = make_env((3, 2), (2, 3), reward_mode=mode)
    outcomes = run(env, [(RIGHT, STAY), (LEFT, STAY), (STAY, DOWN), (RIGHT, STAY)])
    assert [r for r, _ in outcomes] == [2.0, -0.1, 2.0, 10.0]
    assert [d for _, d in outcomes] == [False, False, False, True]


@pytest.mark.parametrize("mode", ["arrival", "per_step", "goal"])
def test_both_arriving_on_the_same_step_pay_exactly_ten(mode: str) -> None:
    env = make_env((3, 2), (2, 3), reward_mode=mode)
    (_, reward, done) = env.step(RIGHT, DOWN, 0.0, 0.0)
    assert reward == 10.0 and done is True


def test_step_cost_when_nobody_arrives() -> None:
    env = make_env((0, 0), (4, 0))
    assert run(env, [(STAY, STAY)]) == [(-0.1, False)]


def test_done_at_max_steps_and_not_before() -> None:
    env = make_env((0, 0), (4, 0), max_steps=3)
    assert [d for _, d in run(env, [(STAY, STAY)] * 3)] == [False, False, True]
    with pytest.raises(ValueError, match="reset"):
        env.step(STAY, STAY, 0.0, 0.0)
    env.reset()
    env.step(STAY, STAY, 0.0, 0.0)  # a new episode may start


def test_vector_terminated_and_truncated_are_separate() -> None:
    env = VectorMultiAgentEnv(2, grid=GRID, max_steps=1, auto_reset=False)
    env.reset(positions=np.array([[[3, 2], [2, 3]], [[0, 0], [4, 0]]]))
    _, rewards, terminated, truncated, info = env.step(
        np.array([[RIGHT, DOWN], [STAY, STAY]]), np.zeros((2, 2))
    )
    assert rewards.dtype == np.float64 and rewards.tolist() == [10.0, -0.1]
    assert terminated.tolist() == [True, False]
    assert truncated.tolist() == [False, True]  # success on the last step is not truncation
    assert info["on_target"].tolist() == [[True, True], [False, False]]
    assert info["positions"].tolist() == [[[3, 3], [3, 3]], [[0, 0], [4, 0]]]
    with pytest.raises(ValueError, match="reset"):
        env.step(np.full((2, 2), STAY), np.zeros((2, 2)))


def test_auto_reset_starts_new_episodes_and_reports_the_final_state() -> None:
    env = VectorMultiAgentEnv(2, grid=GRID, seed=3)
    env.reset(positions=np.array([[[3, 2], [2, 3]], [[0, 0], [4, 0]]]))
    obs, _, terminated, _, info = env.step(np.array([[RIGHT, DOWN], [STAY, STAY]]), np.ones((2, 2)))
    assert terminated.tolist() == [True, False]
    assert info["steps"].tolist() == [1, 1]
    assert env.steps.tolist() == [0, 1]
    assert np.array_equal(info["final_obs"][1], obs[1])  # unfinished row: the same
    assert info["final_obs"][0, 0, 4] == 2 and info["final_obs"][0, 0, 9] == 1.0
    assert obs[0, :, 9].tolist() == [0.0, 0.0]  # the new episode starts with no message
    new_a, new_b = env.positions[0]
    assert tuple(new_a) != tuple(new_b)
    assert GRID[tuple(new_a)] == 0 and GRID[tuple(new_b)] == 0


@pytest.mark.parametrize(("mode", "expected"), [("arrival", -0.1), ("per_step", 2.0)])
def test_starting_on_the_target_is_not_an_arrival(mode: str, expected: float) -> None:
    env = make_env((3, 3), (0, 0), reward_mode=mode)
    assert run(env, [(STAY, STAY)]) == [(expected, False)]


def test_default_reward_is_the_assignment_table_over_consecutive_steps() -> None:
    # No agent, then exactly one (A arrives and stays: +2 on every such step), then both.
    env = MultiAgentEnv(grid=GRID)  # the default reward, as a grader builds it
    env.reset(positions=[(3, 1), (1, 3)])
    steps = [(STAY, STAY), (RIGHT, STAY), (RIGHT, STAY), (STAY, DOWN), (STAY, STAY), (STAY, DOWN)]
    assert [r for r, _ in run(env, steps)] == [-0.1, -0.1, 2.0, 2.0, 2.0, 10.0]


def test_agent_positions_are_settable_and_validated() -> None:
    env = make_env((0, 0), (4, 4))
    env.agent_positions = [(3, 2), (2, 3)]
    assert env.agent_positions == [(3, 2), (2, 3)]
    assert env._get_observation(0)[5] == 2  # the target is now right of A
    (_, reward, done) = env.step(RIGHT, DOWN, 0.0, 0.0)  # the next step starts from there
    assert (reward, done) == (10.0, True)
    env.reset()
    for bad in ([(1, 1), (0, 0)], [(-1, 0), (0, 0)], [(0, 0), (5, 0)]):
        with pytest.raises(ValueError, match="obstacles"):
            env.agent_positions = bad
    with pytest.raises(ValueError, match="shape"):
        env.agent_positions = [(0, 0)]


def test_starter_attributes_follow_the_state() -> None:
    env = make_env((0, 0), (4, 4))
    assert (env.step_count, env.comm_signals, env.target_pos) == (0, [0.0, 0.0], (3, 3))
    env.step(STAY, STAY, 0.25, 0.75)
    assert (env.step_count, env.comm_signals) == (1, [0.25, 0.75])
    assert isinstance(env.step_count, int) and isinstance(env.target_pos[0], int)
    env.reset()
    assert (env.step_count, env.comm_signals) == (0, [0.0, 0.0])


def test_messages_are_clipped_and_non_numbers_refused() -> None:
    env = make_env((0, 0), (4, 4))
    (obs_a, obs_b), _, _ = env.step(STAY, STAY, -3.0, 7.5)
    assert (obs_b[9], obs_a[9]) == (0.0, 1.0) and env.comm_signals == [0.0, 1.0]
    for bad in (float("nan"), float("inf"), -math.inf, "0.5", None):
        with pytest.raises(ValueError, match="comm_B"):
            env.step(STAY, STAY, 0.5, bad)


@pytest.mark.parametrize("bad", [True, False, np.bool_(True), 2.0, 5, -1, "1", None])
def test_actions_must_be_integers_in_range(bad) -> None:
    env = make_env((0, 0), (4, 4))
    with pytest.raises(ValueError, match="action_A"):
        env.step(bad, STAY, 0.0, 0.0)
    assert env.step(np.int64(1), np.int32(4), 0.0, 0.0)[2] is False  # numpy ints are fine
