"""The solutions are right, checked without trusting the solvers."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest
from environment import MOVES, GridWorldEnv
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from q_iteration import QIteration
from value_iteration import ValueIteration

from tests.conftest import load_problem_module

GAMMA = 0.95


@pytest.fixture(scope="module")
def solved() -> dict:
    env = GridWorldEnv(seed=0)
    vi, qi = ValueIteration(env), QIteration(env)
    values, vi_iterations = vi.solve()
    q_values, qi_iterations = qi.solve()
    return {
        "env": env,
        "vi": vi,
        "qi": qi,
        "values": values,
        "q_values": q_values,
        "vi_iterations": vi_iterations,
        "qi_iterations": qi_iterations,
    }


def test_per_state_methods_equal_the_vectorised_sweep(solved) -> None:
    vi, qi = solved["vi"], solved["qi"]
    rng = np.random.default_rng(0)
    values, q_values = rng.normal(size=25) * 5, rng.normal(size=(25, 4)) * 5
    sweep_q = vi.model.action_values(values, GAMMA)
    next_q = qi.model.action_values(q_values.max(axis=1), GAMMA)
    for state in range(25):
        np.testing.assert_allclose(vi.compute_q_values(state, values), sweep_q[state])
        assert vi.bellman_backup(state, values) == pytest.approx(sweep_q[state].max())
        for action in range(4):
            assert qi.bellman_update(state, action, q_values) == pytest.approx(
                next_q[state, action]
            )


def test_backup_equals_the_textbook_sum_over_get_transition_prob(solved) -> None:
    env, vi = solved["env"], solved["vi"]
    values = np.random.default_rng(1).normal(size=25)
    for state in range(25):
        if env.is_terminal(state) or not env.is_valid_pos(env.state_to_pos(state)):
            continue
        for action in range(4):
            textbook = sum(
                p * (env.get_reward(state, action, s2) + GAMMA * values[s2])
                for s2, p in env.get_transition_prob(state, action).items()
            )
            assert vi.compute_q_values(state, values)[action] == pytest.approx(textbook)


def test_stopping_rule_and_contraction(solved) -> None:
    for name in ("vi", "qi"):
        history = solved[name].history
        assert len(history) == solved[f"{name}_iterations"]
        assert history[-1] < 1e-4 <= history[-2]
        for k in range(1, len(history)):  # ||x_{k+1} - x_k|| <= gamma ||x_k - x_{k-1}||
            assert history[k] <= GAMMA * history[k - 1] + 1e-12


def test_the_course_solution_is_unchanged(solved) -> None:
    """31 sweeps each and V(start) = 4.9055 (gamma 0.95, epsilon 1e-4), as published."""
    assert solved["vi_iterations"] == solved["qi_iterations"] == 31
    assert solved["values"][0] == pytest.approx(4.905474846680396, abs=1e-12)
    assert solved["qi"].extract_values(solved["q_values"])[0] == pytest.approx(
        4.905474846680396, abs=1e-12
    )


def test_value_and_q_iteration_agree(solved) -> None:
    qi_values = solved["qi"].extract_values(solved["q_values"])
    np.testing.assert_allclose(qi_values, solved["values"], atol=2e-4 / (1 - GAMMA))
    q_star = solved["vi"].model.action_values(solved["values"], GAMMA)
    rows = np.arange(25)
    qi_policy = solved["qi"].extract_policy(solved["q_values"])
    assert np.all(q_star[rows, qi_policy] >= q_star.max(axis=1) - 1e-3)


def test_exact_policy_evaluation_is_within_the_residual_bound(solved) -> None:
    vi, values = solved["vi"], solved["values"]
    policy = vi.extract_policy(values)
    policy_values = vi.model.evaluate_policy(policy, GAMMA)
    bound = vi.compute_bellman_error(values) / (1 - GAMMA)
    assert np.max(np.abs(policy_values - values)) <= bound
    assert bound < 1e-3


def test_monte_carlo_return_contains_v_start() -> None:
    train = load_problem_module("problem1", "train")
    env = GridWorldEnv(seed=2024)
    vi = ValueIteration(env)
    values, _ = vi.solve()
    estimate = train.monte_carlo_return(env, vi.extract_policy(values), GAMMA, episodes=5000)
    low, high = estimate["ci99"]
    assert low <= values[0] <= high
    assert high - low < 0.2  # the interval is tight enough to mean something


def test_without_drift_the_policy_walks_a_shortest_safe_path() -> None:
    env = GridWorldEnv(prob_drift=0.0)
    vi = ValueIteration(env)
    values, _ = vi.solve()
    policy = vi.extract_policy(values)
    safe_distance = _distances_avoiding_penalties(env)
    assert safe_distance[0] == 8
    for state in range(25):
        pos = env.state_to_pos(state)
        if env.is_terminal(state) or not env.is_valid_pos(pos):
            continue
        path = _follow(env, policy, pos)
        assert path[-1] == env.goal_pos
        assert len(path) - 1 == safe_distance[state], (pos, path)
        assert not set(path[1:]) & set(env.penalties)
    start_value = sum(-0.1 * GAMMA**t for t in range(7)) + 10 * GAMMA**7
    assert values[0] == pytest.approx(start_value, abs=1e-3)


def _follow(env: GridWorldEnv, policy: np.ndarray, pos: tuple[int, int]) -> list[tuple[int, int]]:
    path = [pos]
    while path[-1] != env.goal_pos and len(path) <= 25:
        dr, dc = MOVES[int(policy[env.pos_to_state(path[-1])])]
        step = (path[-1][0] + dr, path[-1][1] + dc)
        path.append(step if env.is_valid_pos(step) else path[-1])
    return path


def _distances_avoiding_penalties(env: GridWorldEnv) -> dict[int, int]:
    """Breadth-first search back from the goal through free, non-penalty cells."""
    distance = {env.pos_to_state(env.goal_pos): 0}
    queue = deque([env.goal_pos])
    while queue:
        r, c = queue.popleft()
        for dr, dc in MOVES:
            prev = (r + dr, c + dc)
            state = env.pos_to_state(prev) if env.is_valid_pos(prev) else None
            if state is None or state in distance:
                continue
            distance[state] = distance[env.pos_to_state((r, c))] + 1
            if prev not in env.penalties:  # a path may start on a penalty cell, not cross one
                queue.append(prev)
    return distance


def goal_is_reachable(layout: list[str]) -> bool:
    """Breadth-first search from S to G through cells that are not '#'."""
    cells = {(r, c): ch for r, row in enumerate(layout) for c, ch in enumerate(row)}
    start = next(pos for pos, ch in cells.items() if ch == "S")
    seen, queue = {start}, deque([start])
    while queue:
        r, c = queue.popleft()
        if cells[(r, c)] == "G":
            return True
        for dr, dc in MOVES:
            nxt = (r + dr, c + dc)
            if cells.get(nxt, "#") != "#" and nxt not in seen:  # off the grid counts as a wall
                seen.add(nxt)
                queue.append(nxt)
    return False


@st.composite
def small_layouts(draw) -> list[str]:
    size = draw(st.integers(3, 6))
    cells = draw(st.lists(st.sampled_from(".....#P"), min_size=size * size, max_size=size * size))
    start, goal = draw(
        st.lists(st.integers(0, size * size - 1), min_size=2, max_size=2, unique=True)
    )
    cells[start], cells[goal] = "S", "G"
    return ["".join(cells[r * size : (r + 1) * size]) for r in range(size)]


@settings(max_examples=60, deadline=None)
@given(layout=small_layouts())
def test_a_layout_is_accepted_exactly_when_its_goal_is_reachable(layout: list[str]) -> None:
    if goal_is_reachable(layout):
        assert GridWorldEnv(layout=layout).goal_pos is not None
    else:
        with pytest.raises(ValueError, match="cannot be reached from the start"):
            GridWorldEnv(layout=layout)


@settings(max_examples=40, deadline=None)
@given(layout=small_layouts(), drift=st.sampled_from([0.0, 0.1, 0.25]))
def test_solvers_agree_on_random_layouts(layout: list[str], drift: float) -> None:
    assume(goal_is_reachable(layout))
    env = GridWorldEnv(layout=layout, prob_drift=drift)
    vi, qi = ValueIteration(env), QIteration(env)
    values, _ = vi.solve()
    q_values, _ = qi.solve()
    bound = vi.compute_bellman_error(values) / (1 - GAMMA)
    np.testing.assert_allclose(qi.extract_values(q_values), values, atol=2 * bound + 1e-9)
    policy_values = vi.model.evaluate_policy(vi.extract_policy(values), GAMMA)
    assert np.max(np.abs(policy_values - values)) <= bound + 1e-9
    assert math.isfinite(values.sum())
