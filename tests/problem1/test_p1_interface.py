"""Every problem-1 item of INTERFACES.md: names, defaults, return types and shapes."""

from __future__ import annotations

import numpy as np
import pytest
from environment import GridWorldEnv
from q_iteration import QIteration
from value_iteration import ValueIteration
from visualize import GridWorldVisualizer


@pytest.fixture(scope="module")
def env() -> GridWorldEnv:
    return GridWorldEnv(seed=0)


def test_environment_attributes_match_the_course(env: GridWorldEnv) -> None:
    assert env.grid_size == 5
    assert env.max_steps == 50
    assert env.action_space == 4
    assert env.start_pos == (0, 0)
    assert env.goal_pos == (4, 4)
    assert env.obstacles == [(1, 2), (2, 1)]
    assert env.penalties == [(3, 3), (3, 0)]
    assert (env.goal_reward, env.penalty_reward, env.step_cost) == (10.0, -5.0, -0.1)
    assert (env.prob_intended, env.prob_drift) == pytest.approx((0.8, 0.1))


def test_action_names_follow_the_clockwise_numbering(env: GridWorldEnv) -> None:
    assert env.action_names == ["UP", "RIGHT", "DOWN", "LEFT"]
    assert GridWorldEnv.action_names == ["UP", "RIGHT", "DOWN", "LEFT"]


def test_next_positions_merge_outcomes_that_land_on_the_same_cell(env: GridWorldEnv) -> None:
    assert env._get_next_positions((0, 0), 0) == [((0, 0), 0.9), ((0, 1), 0.1)]
    for state in range(25):
        pos = env._state_to_pos(state)
        for action in range(4):
            merged = env._get_next_positions(pos, action)
            cells = [cell for cell, _ in merged]
            assert len(cells) == len(set(cells))
            assert sum(p for _, p in merged) == pytest.approx(1.0)
            as_states = {env._pos_to_state(cell): p for cell, p in merged}
            assert as_states == pytest.approx(env.get_transition_prob(state, action))


def test_seed_is_the_only_required_constructor_argument() -> None:
    assert GridWorldEnv().grid_size == 5
    assert GridWorldEnv(seed=None).goal_pos == (4, 4)


def test_environment_methods_return_plain_python_types(env: GridWorldEnv) -> None:
    state = env.reset()
    assert type(state) is int and state == 0
    next_state, reward, done, info = env.step(1)
    assert (type(next_state), type(reward), type(done), type(info)) == (int, float, bool, dict)
    probs = env.get_transition_prob(0, 1)
    assert all(type(s) is int and type(p) is float for s, p in probs.items())
    assert type(env.get_reward(0, 1, 1)) is float
    assert type(env.is_terminal(24)) is bool and env.is_terminal(24)
    assert not env.is_terminal(0)
    assert type(env._is_valid_pos((0, 0))) is bool
    assert type(env._calculate_reward((3, 3))) is float
    outcomes = env._get_next_positions((2, 3), 0)
    assert all(isinstance(pos, tuple) and len(pos) == 2 and type(p) is float for pos, p in outcomes)


def test_state_indices_are_row_major(env: GridWorldEnv) -> None:
    for state in range(25):
        row, col = env._state_to_pos(state)
        assert (row, col) == (state // 5, state % 5)
        assert env._pos_to_state((row, col)) == state
        assert type(env._pos_to_state((row, col))) is int


def test_render_prints_the_grid_and_values(env: GridWorldEnv, capsys) -> None:
    env.reset()
    env.render()
    grid = capsys.readouterr().out.split("\n")
    assert grid[0].split() == ["A", ".", ".", ".", "."]
    assert grid[1].split()[2] == "#" and grid[4].split()[4] == "G"
    env.render(np.arange(25, dtype=float))
    assert "24.00" in capsys.readouterr().out


@pytest.mark.parametrize("solver_class", [ValueIteration, QIteration])
def test_solver_constructor_defaults(env: GridWorldEnv, solver_class) -> None:
    solver = solver_class(env)
    assert solver.gamma == 0.95 and solver.epsilon == 1e-4
    assert solver.n_states == 25 and solver.n_actions == 4


def test_value_iteration_interface(env: GridWorldEnv) -> None:
    vi = ValueIteration(env)
    result = vi.solve()
    assert isinstance(result, tuple) and len(result) == 2
    values, iterations = result
    assert isinstance(values, np.ndarray) and values.shape == (25,)
    assert type(iterations) is int and 1 <= iterations <= 1000
    assert vi.compute_q_values(0, values).shape == (4,)
    policy = vi.extract_policy(values)
    assert policy.shape == (25,) and policy.dtype in (np.int32, np.int64)
    assert set(np.unique(policy)) <= {0, 1, 2, 3}
    assert type(vi.bellman_backup(0, values)) is float
    assert vi.bellman_backup(24, values) == 0.0
    error = vi.compute_bellman_error(values)
    assert type(error) is float and error >= 0.0


def test_q_iteration_interface(env: GridWorldEnv) -> None:
    qi = QIteration(env)
    q_values, iterations = qi.solve(max_iterations=1000)
    assert q_values.shape == (25, 4) and type(iterations) is int
    assert type(qi.bellman_update(0, 1, q_values)) is float
    policy = qi.extract_policy(q_values)
    assert policy.shape == (25,) and policy.dtype in (np.int32, np.int64)
    assert qi.extract_values(q_values).shape == (25,)
    assert type(qi.compute_bellman_error(q_values)) is float
    assert qi.compute_bellman_error(q_values) >= 0.0


def test_max_iterations_caps_the_sweeps(env: GridWorldEnv) -> None:
    values, iterations = ValueIteration(env).solve(max_iterations=3)
    assert iterations == 3
    assert ValueIteration(env).compute_bellman_error(values) > 1e-4


def test_visualizer_methods_return_figures(env: GridWorldEnv) -> None:
    vi = ValueIteration(env)
    values, _ = vi.solve()
    policy = vi.extract_policy(values)
    qi = QIteration(env)
    q_values, _ = qi.solve()
    visualizer = GridWorldVisualizer(grid_size=5)
    figures = [
        visualizer.plot_value_function(values, "V"),
        visualizer.plot_policy(policy, "pi"),
        visualizer.plot_q_function(q_values, "Q"),
        visualizer.plot_convergence(vi.history, qi.history),
        visualizer.create_comparison_figure(
            values, qi.extract_values(q_values), policy, qi.extract_policy(q_values)
        ),
    ]
    assert [len(f.axes) >= 1 for f in figures] == [True] * 5
    assert len(figures[2].axes) == 5  # four action panels and a colour bar


@pytest.mark.parametrize(
    ("value", "label"), [(9.2, "9.2"), (9.94, "9.9"), (9.96, "10"), (-5.0, "-5.0")]
)
def test_compact_value_labels_drop_the_decimal_from_9_95_up(value: float, label: str) -> None:
    """Fig. 3's small panels print one decimal, or none from 9.95 up ("10", not "10.0")."""
    assert GridWorldVisualizer._compact_label(value) == label
