"""The vectorised environment against the single one, map generation and storage, and
bad input for both environments."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from analysis.episodes import target_distances
from analysis.runs import load_map
from batch.plumbing import save_map
from multi_agent_env import MultiAgentEnv
from vector_env import VectorMultiAgentEnv, generate_map

GRID = np.array([[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 0, 0]])


def test_single_and_vector_env_give_identical_trajectories() -> None:
    single = MultiAgentEnv(seed=641)
    vector = VectorMultiAgentEnv(1, seed=641)
    assert np.array_equal(single.grid, vector.grid)
    rng = np.random.default_rng(0)
    obs_a, obs_b = single.reset(seed=11)
    vector_obs = vector.reset(seed=11)
    episodes = 0
    for _ in range(400):
        assert np.array_equal(vector_obs[0], np.stack([obs_a, obs_b]))
        actions, messages = rng.integers(5, size=(1, 2)), rng.random((1, 2))
        (obs_a, obs_b), reward, done = single.step(*actions[0], *messages[0])
        vector_obs, rewards, terminated, truncated, info = vector.step(actions, messages)
        assert rewards[0] == reward
        assert done == bool(terminated[0] or truncated[0])
        if done:  # the vector env has already started the next episode
            assert np.array_equal(info["final_obs"][0], np.stack([obs_a, obs_b]))
            obs_a, obs_b = single.reset()
            episodes += 1
    assert episodes >= 5


def test_vector_rows_are_independent_copies() -> None:
    starts = np.array([[[0, 0], [3, 3]], [[2, 0], [0, 3]], [[3, 0], [0, 2]]])
    vector = VectorMultiAgentEnv(3, grid=GRID, max_steps=20, auto_reset=False)
    vector_obs = vector.reset(positions=starts)
    singles = [MultiAgentEnv(grid=GRID, max_steps=20) for _ in starts]
    single_obs = [
        np.stack(env.reset(positions=start)) for env, start in zip(singles, starts, strict=True)
    ]
    assert np.array_equal(vector_obs, np.stack(single_obs))
    rng = np.random.default_rng(1)
    for _ in range(20):
        actions, messages = rng.integers(5, size=(3, 2)), rng.random((3, 2))
        vector_obs, rewards, terminated, truncated, _ = vector.step(actions, messages)
        for row, env in enumerate(singles):
            (obs_a, obs_b), reward, done = env.step(*actions[row], *messages[row])
            assert np.array_equal(vector_obs[row], np.stack([obs_a, obs_b]))
            assert rewards[row] == reward
            assert done == bool(terminated[row] or truncated[row])
        if (terminated | truncated).any():
            break


def test_reset_seed_reproduces_placements() -> None:
    env = VectorMultiAgentEnv(64, seed=641)
    first = env.reset(seed=7)
    assert np.array_equal(env.reset(seed=7), first)
    assert not np.array_equal(env.reset(seed=8), first)
    other = VectorMultiAgentEnv(64, seed=641)
    assert np.array_equal(other.reset(seed=7), first)


def test_reset_places_agents_on_distinct_free_cells() -> None:
    env = VectorMultiAgentEnv(5000, seed=2)
    env.reset(seed=0)
    rows, cols = env.positions[..., 0], env.positions[..., 1]
    assert (env.grid[rows, cols] == 0).all()  # never an obstacle or the target
    assert (env.positions[:, 0] != env.positions[:, 1]).any(axis=1).all()
    used = {tuple(cell) for cell in env.positions.reshape(-1, 2).tolist()}
    assert used == {tuple(cell) for cell in np.argwhere(env.grid == 0).tolist()}  # every free cell


def test_generate_map_follows_the_design() -> None:
    state = np.random.get_state()[1].copy()
    for seed in range(30):
        grid = generate_map((10, 10), seed)
        assert np.array_equal(grid, generate_map((10, 10), seed))
        assert 3 <= (grid == 1).sum() <= 6
        assert (grid == 2).sum() == 1
        assert (grid[[0, 0, -1, -1], [0, -1, 0, -1]] != 1).all()  # corners never blocked
        assert ((grid == 1) | (target_distances(grid) >= 0)).all()  # all connected
    assert np.array_equal(np.random.get_state()[1], state)  # global RNG untouched
    assert not np.array_equal(generate_map((10, 10), 0), generate_map((10, 10), 1))


def test_env_seed_draws_the_map_and_grid_overrides_it() -> None:
    assert np.array_equal(MultiAgentEnv(seed=641).grid, generate_map((10, 10), 641))
    env = VectorMultiAgentEnv(2, grid_size=(10, 10), grid=GRID)
    assert env.grid_size == (4, 4) and np.array_equal(env.grid, GRID)
    assert env.target_position == (2, 2)


def test_map_round_trip(tmp_path: Path) -> None:
    grid = generate_map((7, 9), 3)
    path = tmp_path / "maps" / "map.json"
    save_map(path, grid)
    loaded = load_map(path)
    assert np.array_equal(loaded, grid)
    assert sorted(p.name for p in path.parent.iterdir()) == ["map.json"]  # no temp left


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ({"grid": [[0, 0, 0], [0, 2, 0], [0, 0]]}, "rectangular"),
        ({"grid": [[0, 0, 0], [0, 3, 0], [0, 2, 0]]}, "values"),
        ({"grid": [[0, 0, 0], [0, 2, 0], [0, 2, 0]]}, "exactly one target"),
        ({"grid": [[0, 0, 0], [0, 0, 0], [0, 0, 0]]}, "exactly one target"),
        ({"grid": [[0, 1, 0], [1, 1, 0], [0, 0, 2]]}, "not connected"),
        ({"grid": [[0, 0], [0, 2]]}, "at least 3×3"),
        ({"grid": [[0.5, 0, 0], [0, 2, 0], [0, 0, 0]]}, "integers"),
        ({"rows": []}, "'grid'"),
    ],
)
def test_load_map_names_the_problem(tmp_path: Path, content: dict, problem: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(ValueError, match=problem) as error:
        load_map(path)
    assert "bad.json" in str(error.value)


def test_load_map_rejects_invalid_json_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_map(path)
    with pytest.raises(FileNotFoundError):
        load_map(tmp_path / "missing.json")


def test_larger_observation_window() -> None:
    env = MultiAgentEnv(grid=GRID, obs_window=5)
    obs_a, _ = env.reset(positions=[(0, 0), (3, 3)])
    assert obs_a.shape == (27,)
    patch = obs_a[:25].reshape(5, 5)
    assert (patch[:2] == -1).all() and (patch[:, :2] == -1).all()
    assert patch[2:, 2:].tolist() == [[0, 0, 0], [0, 1, 0], [0, 0, 2]]
    (obs_a, obs_b), _, _ = env.step(4, 4, 0.5, 0.25)
    assert obs_a[25] == 0.25 and obs_b[25] == 0.5
    assert obs_a[26] == pytest.approx(np.hypot(3, 3) / np.hypot(4, 4))


# ------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "problem"),
    [
        ({"obs_window": 4}, "odd"),
        ({"obs_window": 2}, "odd"),
        ({"obs_window": 1}, ">= 3"),
        ({"grid_size": (2, 5)}, "at least 3×3"),
        ({"grid_size": (2, 2)}, "at least 3×3"),
        ({"grid_size": (3, 3), "seed": 0}, "no connected 3×3 map"),
        ({"grid": np.array([[0, 1, 0], [1, 1, 0], [0, 0, 2]])}, "not connected"),
        ({"max_steps": 0}, "max_steps"),
        ({"max_steps": None}, "max_steps must be a positive integer"),
        ({"max_steps": 2.5}, "max_steps must be a positive integer"),
        ({"obs_window": None}, "obs_window"),
        ({"seed": -1}, "seed must be None or a non-negative integer"),
        ({"seed": 1.5}, "seed must be None or a non-negative integer"),
        ({"seed": "641"}, "seed must be None or a non-negative integer"),
        ({"reward_mode": "shaped"}, "reward_mode"),
    ],
)
@pytest.mark.parametrize("make", [MultiAgentEnv, lambda **kw: VectorMultiAgentEnv(4, **kw)])
def test_bad_construction_raises(make, kwargs: dict, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        make(**kwargs)


def test_bad_vector_size_raises() -> None:
    with pytest.raises(ValueError, match="n_envs"):
        VectorMultiAgentEnv(0)


@pytest.mark.parametrize(
    ("action_a", "comm_a", "problem"),
    [
        (5, 0.5, "0..4"),
        (-1, 0.5, "0..4"),
        (1.5, 0.5, "integer"),
        (True, 0.5, "boolean"),
        (1, float("nan"), "comm_A must be a finite number"),
        (1, float("inf"), "comm_A must be a finite number"),
        ([1, 2], 0.5, "single number"),
    ],
)
def test_single_env_bad_step_input_raises(action_a, comm_a, problem: str) -> None:
    env = MultiAgentEnv(seed=641)
    env.reset()
    before = env.agent_positions
    with pytest.raises(ValueError, match=problem):
        env.step(action_a, 0, comm_a, 0.5)
    assert env.agent_positions == before  # a refused step changes nothing


@pytest.mark.parametrize(
    ("actions", "messages", "problem"),
    [
        (np.full((3, 2), 5), np.zeros((3, 2)), "0..4"),
        (np.full((3, 2), -1), np.zeros((3, 2)), "0..4"),
        (np.full((3, 2), 1.0), np.zeros((3, 2)), "integers"),
        (np.zeros((3, 3), dtype=int), np.zeros((3, 2)), "shape"),
        (np.zeros((3, 2), dtype=int), np.full((3, 2), np.nan), "finite"),
        (np.zeros((3, 2), dtype=int), np.full((3, 2), -np.inf), "finite"),
        (np.zeros((3, 2), dtype=bool), np.zeros((3, 2)), "integers"),
        (np.zeros((3, 2), dtype=int), np.zeros(3), "shape"),
    ],
)
def test_vector_env_bad_step_input_raises(actions, messages, problem: str) -> None:
    env = VectorMultiAgentEnv(3, seed=641)
    before = env.positions
    with pytest.raises(ValueError, match=problem):
        env.step(actions, messages)
    assert np.array_equal(env.positions, before)


@pytest.mark.parametrize(
    ("positions", "problem"),
    [
        ([(1, 1), (0, 0)], "not obstacles"),
        ([(4, 0), (0, 0)], "inside the 4x4 grid"),
        ([(2, 2), (2, 2)], "both agents start on the target"),
    ],
)
def test_bad_start_positions_raise(positions: list, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        MultiAgentEnv(grid=GRID).reset(positions=positions)


def test_bad_helper_arguments_raise() -> None:
    env = MultiAgentEnv(grid=GRID)
    with pytest.raises(ValueError, match="agent_idx"):
        env._get_observation(2)
    with pytest.raises(ValueError, match="obstacle"):
        env._apply_action((1, 1), 0)
    with pytest.raises(ValueError, match="0..4"):
        env._apply_action((0, 0), 7)
    with pytest.raises(ValueError, match="0..4"):
        env._apply_action((0, 0), True)
