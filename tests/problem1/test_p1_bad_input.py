"""Bad input is refused with a ValueError that names the problem."""

from __future__ import annotations

import numpy as np
import pytest
from environment import GridWorldEnv
from file_io import atomic_save_json
from q_iteration import QIteration
from value_iteration import ValueIteration

from tests.conftest import load_problem_module


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


@pytest.mark.parametrize("solver_class", [ValueIteration, QIteration])
@pytest.mark.parametrize("max_iterations", [2.5, "10", None, True, -3])
def test_max_iterations_must_be_a_positive_integer(solver_class, max_iterations) -> None:
    with pytest.raises(ValueError, match="max_iterations must be an integer >= 1"):
        solver_class(GridWorldEnv()).solve(max_iterations)


@pytest.mark.parametrize("solver_class", [ValueIteration, QIteration])
@pytest.mark.parametrize(
    ("gamma", "epsilon", "name"),
    [
        (float("nan"), 1e-4, "gamma"),
        (-0.1, 1e-4, "gamma"),
        ("0.9", 1e-4, "gamma"),
        (0.95, float("inf"), "epsilon"),
        (0.95, float("nan"), "epsilon"),
        (0.95, -1e-4, "epsilon"),
    ],
)
def test_non_finite_or_out_of_range_parameters(solver_class, gamma, epsilon, name) -> None:
    with pytest.raises(ValueError, match=name):
        solver_class(GridWorldEnv(), gamma=gamma, epsilon=epsilon)


@pytest.mark.parametrize("max_steps", [2.5, "50", None, True, 0])
def test_max_steps_must_be_a_positive_integer(max_steps) -> None:
    with pytest.raises(ValueError, match="max_steps must be an integer >= 1"):
        GridWorldEnv(max_steps=max_steps)


@pytest.mark.parametrize("layout", ["S.G", {"S": (0, 0), "G": (0, 1)}, 5, b"SG"])
def test_a_layout_must_be_a_list_of_rows(layout) -> None:
    with pytest.raises(ValueError, match="layout must be a list of row strings"):
        GridWorldEnv(layout=layout)


@pytest.mark.parametrize(
    "layout",
    [
        ["S#.", "##.", "..G"],  # the start is walled in
        ["S..", "..#", ".#G"],  # the goal is walled in
    ],
)
def test_a_layout_whose_goal_cannot_be_reached_is_refused(layout: list[str]) -> None:
    with pytest.raises(ValueError, match=r"goal \(2, 2\) cannot be reached from the start"):
        GridWorldEnv(layout=layout)


def test_non_finite_values_are_refused() -> None:
    env = GridWorldEnv()
    vi, qi = ValueIteration(env), QIteration(env)
    values = np.zeros(25)
    values[3] = np.nan
    for method in (vi.extract_policy, vi.compute_bellman_error):
        with pytest.raises(ValueError, match="values must be finite"):
            method(values)
    with pytest.raises(ValueError, match="values must be finite"):
        vi.bellman_backup(0, np.full(25, np.inf))
    q_values = np.zeros((25, 4))
    q_values[0, 2] = np.nan
    for method in (qi.extract_policy, qi.extract_values, qi.compute_bellman_error):
        with pytest.raises(ValueError, match="q_values must be finite"):
            method(q_values)


def test_json_results_never_hold_nan_or_infinity(tmp_path) -> None:
    for bad in (float("nan"), float("inf"), -float("inf")):
        with pytest.raises(ValueError, match="must be finite"):
            atomic_save_json(tmp_path / "x.json", {"a": [1.0, {"b": bad}]})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("episodes", [1, 0, -5, 2.5])
def test_monte_carlo_check_needs_two_episodes(episodes) -> None:
    train = load_problem_module("problem1", "train")
    with pytest.raises(ValueError, match="episodes must be an integer >= 2"):
        train.monte_carlo_return(GridWorldEnv(seed=0), np.ones(25, dtype=int), 0.95, episodes)


def test_wrong_shapes_are_refused() -> None:
    env = GridWorldEnv()
    with pytest.raises(ValueError, match=r"values must have shape \(25,\)"):
        ValueIteration(env).bellman_backup(0, np.zeros(24))
    with pytest.raises(ValueError, match=r"q_values must have shape \(25, 4\)"):
        QIteration(env).extract_policy(np.zeros((25, 3)))


def test_drift_probability_is_checked() -> None:
    with pytest.raises(ValueError, match="prob_drift"):
        GridWorldEnv(prob_drift=0.6)
