"""Bad input is refused with a ValueError that names the problem."""

from __future__ import annotations

import numpy as np
import pytest
from environment import GridWorldEnv
from q_iteration import QIteration
from value_iteration import ValueIteration


@pytest.mark.parametrize("action", [4, -1, 100])
def test_action_outside_range(action: int) -> None:
    env = GridWorldEnv(seed=0)
    with pytest.raises(ValueError, match="action must be in 0..3"):
        env.step(action)
    with pytest.raises(ValueError, match="action must be in 0..3"):
        env.get_transition_prob(0, action)


@pytest.mark.parametrize("action", [1.5, 1.0, "1", None, True])
def test_non_integer_action(action) -> None:
    with pytest.raises(ValueError, match="action must be an integer"):
        GridWorldEnv(seed=0).step(action)


def test_numpy_integer_actions_are_accepted() -> None:
    env = GridWorldEnv(seed=0)
    assert type(env.step(np.int64(1))[0]) is int


@pytest.mark.parametrize("state", [25, -1, 1000])
def test_state_outside_range(state: int) -> None:
    env = GridWorldEnv(seed=0)
    with pytest.raises(ValueError, match=r"state must be in 0..24"):
        env.get_transition_prob(state, 0)
    with pytest.raises(ValueError, match=r"state must be in 0..24"):
        env._state_to_pos(state)
    with pytest.raises(ValueError, match=r"state must be in 0..24"):
        ValueIteration(env).compute_q_values(state, np.zeros(25))


@pytest.mark.parametrize(
    ("layout", "message"),
    [
        (["S..", "...", "..."], "exactly one goal"),
        (["...", "...", "..G"], "exactly one start"),
        (["S.G", "S..", "..."], "exactly one start"),
        (["S..", "..", "..G"], "row 1 has 2 cells, expected 3"),
        (["S..", ".x.", "..G"], "unknown symbol 'x'"),
        ([], "layout is empty"),
    ],
)
def test_impossible_layouts(layout: list[str], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        GridWorldEnv(layout=layout)


def test_step_after_the_goal_raises() -> None:
    env = GridWorldEnv(layout=["SG", ".."], prob_drift=0.0)
    assert env.step(1)[2] is True
    with pytest.raises(ValueError, match="episode ended; call reset"):
        env.step(1)


@pytest.mark.parametrize("solver_class", [ValueIteration, QIteration])
def test_solver_parameters_are_checked(solver_class) -> None:
    env = GridWorldEnv()
    with pytest.raises(ValueError, match="gamma"):
        solver_class(env, gamma=1.0)
    with pytest.raises(ValueError, match="epsilon"):
        solver_class(env, epsilon=0.0)
    with pytest.raises(ValueError, match="max_iterations"):
        solver_class(env).solve(max_iterations=0)


def test_wrong_shapes_are_refused() -> None:
    env = GridWorldEnv()
    with pytest.raises(ValueError, match=r"values must have shape \(25,\)"):
        ValueIteration(env).bellman_backup(0, np.zeros(24))
    with pytest.raises(ValueError, match=r"q_values must have shape \(25, 4\)"):
        QIteration(env).extract_policy(np.zeros((25, 3)))


def test_drift_probability_is_checked() -> None:
    with pytest.raises(ValueError, match="prob_drift"):
        GridWorldEnv(prob_drift=0.6)
