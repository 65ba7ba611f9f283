"""Several maps in one vectorised env, the map pools, shared weights, shaping, the study."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.held_out import held_out_maps
from analysis.map_sets import HELD_OUT_MAP_SEEDS, training_maps, validation_maps
from multi_agent_env import MultiAgentEnv
from settings import validated
from studies import map_pool_study
from studies.pool_training import PoolConfig, PooledVectorEnv, PoolTrainer
from studies.staging import run_command, staged_output
from vector_env import DEFAULT_MAP_SEED, VectorMultiAgentEnv, generate_map

MAPS = np.stack([generate_map((10, 10), seed) for seed in (0, 1, 2, 3)])


def random_steps(env: VectorMultiAgentEnv, steps: int, seed: int) -> list[tuple]:
    rng = np.random.default_rng(seed)
    return [
        env.step(rng.integers(5, size=(env.n_envs, 2)), rng.random((env.n_envs, 2)))
        for _ in range(steps)
    ]


# ---------------------------------------------------------------------- one map per copy
def test_each_copy_obeys_its_own_map_like_a_single_map_env() -> None:
    starts = np.array([[[0, 0], [9, 9]], [[0, 9], [9, 0]], [[5, 0], [0, 5]], [[9, 4], [4, 9]]])
    for copy, grid in enumerate(MAPS):  # the start cells must be free on every map
        assert (grid[starts[copy, :, 0], starts[copy, :, 1]] != 1).all()
    stacked = PooledVectorEnv(4, grids=MAPS, max_steps=30, auto_reset=False)
    singles = [VectorMultiAgentEnv(1, grid=g, max_steps=30, auto_reset=False) for g in MAPS]
    obs = stacked.reset(positions=starts)
    for copy, single in enumerate(singles):
        assert np.array_equal(obs[copy], single.reset(positions=starts[copy : copy + 1])[0])
    assert np.array_equal(stacked.target_positions, [[*np.argwhere(g == 2)[0]] for g in MAPS])
    rng = np.random.default_rng(3)
    for _ in range(30):
        actions, messages = rng.integers(5, size=(4, 2)), rng.random((4, 2))
        result = stacked.step(actions, messages)
        for copy, single in enumerate(singles):
            if single._finished.any():
                continue
            expected = single.step(actions[copy : copy + 1], messages[copy : copy + 1])
            for mine, theirs in zip(result[:4], expected[:4], strict=True):
                assert np.array_equal(mine[copy], theirs[0])
            assert np.array_equal(stacked.positions[copy], single.positions[0])


def test_pool_draws_a_map_per_episode_reproducibly() -> None:
    env = PooledVectorEnv(64, map_pool=MAPS, max_steps=5, seed=9)
    first_maps = env.map_indices
    assert set(first_maps.tolist()) == {0, 1, 2, 3}
    seen = {tuple(first_maps)}
    for step in random_steps(env, 20, 0):
        if (step[3]).all():  # every copy cut off at 5 steps: new maps drawn
            seen.add(tuple(env.map_indices))
    assert len(seen) > 1  # maps change between episodes
    rows, cols = env.positions[..., 0], env.positions[..., 1]
    assert (env.grids[env.map_indices[:, None], rows, cols] == 0).all()  # free cells of own map
    obs = env.reset(seed=4)
    again = PooledVectorEnv(64, map_pool=MAPS, max_steps=5, seed=123)
    assert np.array_equal(again.reset(seed=4), obs)
    assert np.array_equal(again.map_indices, env.map_indices)


def test_single_map_path_is_unchanged_by_the_pool_code() -> None:
    one = VectorMultiAgentEnv(8, seed=DEFAULT_MAP_SEED)
    same = VectorMultiAgentEnv(8, grid=generate_map((10, 10), DEFAULT_MAP_SEED), seed=641)
    for a, b in zip(random_steps(one, 60, 1), random_steps(same, 60, 1), strict=True):
        for x, y in zip(a[:4], b[:4], strict=True):
            assert np.array_equal(x, y)
    assert one.target_position == tuple(np.argwhere(one.grid == 2)[0])


def test_several_maps_refuse_single_map_questions_and_bad_stacks() -> None:
    env = PooledVectorEnv(4, grids=MAPS)
    with pytest.raises(ValueError, match="several"):
        _ = env.target_position
    with pytest.raises(ValueError, match="n_envs"):
        PooledVectorEnv(3, grids=MAPS)
    with pytest.raises(ValueError, match="give one of grid, map_pool and grids"):
        PooledVectorEnv(4, grid=MAPS[0], map_pool=MAPS)
    with pytest.raises(ValueError, match="map_pool and grids"):
        PooledVectorEnv(4, map_pool=MAPS, grids=MAPS)
    broken = MAPS.copy()
    broken[2, 0, 1] = broken[2, 1, 0] = 1  # corner (0, 0) cut off
    with pytest.raises(ValueError, match=r"map_pool\[2\].*not connected"):
        PooledVectorEnv(4, map_pool=broken)


def test_coverage_counts_cells_seen_for_the_first_time() -> None:
    grid = np.zeros((5, 5), dtype=np.int64)
    grid[4, 4] = 2
    env = PooledVectorEnv(1, grids=grid[None], track_coverage=True, auto_reset=False)
    env.reset(positions=np.array([[[0, 0], [0, 4]]]))
    right, stay, left = 3, 4, 2
    newly = [
        env.step(np.array([[a, stay]]), np.zeros((1, 2)))[4]["newly_seen"][0]
        for a in (right, stay, left, right, right)
    ]
    # A's view at (0, 0) and B's at (0, 4) cover columns 0-1 and 3-4 of rows 0-1; moving to
    # (0, 1) shows column 2 of both rows; after that every cell of rows 0-1 has been seen.
    assert newly == [2, 0, 0, 0, 0]


# ---------------------------------------------------------------------- the pools
def test_pools_are_deterministic_distinct_and_disjoint_from_the_test_maps() -> None:
    train, valid = training_maps(2000), validation_maps(200)
    assert train.shape == (2000, 10, 10) and valid.shape == (200, 10, 10)
    assert np.array_equal(
        train[:5], np.stack([generate_map((10, 10), 100_000 + i) for i in range(5)])
    )
    test = {g.tobytes() for g in held_out_maps()} | {generate_map((10, 10), 641).tobytes()}
    train_set, valid_set = {g.tobytes() for g in train}, {g.tobytes() for g in valid}
    assert len(train_set) == 2000 and len(valid_set) == 200  # no duplicates within a pool
    assert not train_set & test and not valid_set & test and not train_set & valid_set


# ---------------------------------------------------------------------- trainer
def pool_trainer(tmp_path: Path, **settings) -> PoolTrainer:
    cfg = validated(
        PoolConfig(
            mode="full",
            seed=3,
            total_steps=10**9,
            num_envs=16,
            batch_size=32,
            learning_starts=32,
            buffer_size=4096,
            map_pool=50,
            validation_maps=10,
            output_dir=str(tmp_path),
            **{"target_potential": 0.0} | settings,  # the study's recipe: no arrival term
        ),
    )
    return PoolTrainer(MultiAgentEnv(seed=641), cfg)


def collect(trainer: PoolTrainer, steps: int) -> list[np.ndarray]:
    rollout, learned = trainer.rollout, []
    for _ in range(steps):
        actions, messages = trainer.act(rollout.obs, 1.0, trainer.rng, True)
        next_obs, rewards, terminated, truncated, info = rollout.env.step(actions, messages)
        learned.append(trainer.learning_rewards(rewards, info, rollout.obs) - rewards)
        trainer.store(rollout, actions, messages, rewards, info["final_obs"], terminated, truncated)
        rollout.advance(next_obs, rewards, terminated | truncated)
    return learned


def test_shared_weights_stay_shared_after_updates(tmp_path: Path) -> None:
    trainer = pool_trainer(tmp_path, share_weights=True)
    collect(trainer, 10)
    for _ in range(5):
        trainer.update_networks(32)
    a, b = trainer.online.agent(0).state_dict(), trainer.online.agent(1).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    untrained = pool_trainer(tmp_path, share_weights=True).online.agent(0).state_dict()
    assert not torch.equal(a["hidden.weight"], untrained["hidden.weight"])  # they did learn
    separate = pool_trainer(tmp_path, share_weights=False)
    collect(separate, 10)
    separate.update_networks(32)
    a, b = separate.online.agent(0).state_dict(), separate.online.agent(1).state_dict()
    assert not torch.equal(a["hidden.weight"], b["hidden.weight"])


def test_shared_gradient_is_the_sum_of_both_agents(tmp_path: Path) -> None:
    """update_networks with shared weights steps along the autograd gradient of the TD loss
    summed over the agent axis (one parameter used by both agents)."""
    trainer = pool_trainer(tmp_path, share_weights=True, comm_noise=0.0, max_grad_norm=1e9)
    collect(trainer, 10)
    batch = trainer.sample(32)
    trainer.online.zero_grad(set_to_none=True)
    loss, _, _ = trainer.td_loss(batch)
    loss.backward()
    expected = [p.grad.sum(dim=0) for p in trainer.online.parameters()]
    trainer.sample = lambda batch_size: batch  # the same batch
    stepped = []
    trainer.optimizer.step = lambda **_: stepped.append(
        [p.grad.clone() for p in trainer.online.parameters()]
    )
    trainer.update_networks(32)
    for mine, want in zip(stepped[0], expected, strict=True):
        assert torch.equal(mine[0], mine[1])
        assert torch.allclose(mine[0], want, atol=1e-6)


def test_shaping_adds_the_bonuses_only_to_what_is_learned(tmp_path: Path) -> None:
    trainer = pool_trainer(tmp_path, coverage_bonus=0.05, on_target_bonus=0.1)
    assert trainer.rollout.env.track_coverage
    bonuses = np.concatenate(collect(trainer, 30))
    assert (bonuses >= 0).all() and bonuses.max() > 0
    assert np.allclose(bonuses / 0.05 - np.round(bonuses / 0.05), 0, atol=1e-6)  # 0.1 = 2 x 0.05
    plain = pool_trainer(tmp_path)
    assert not plain.rollout.env.track_coverage
    assert np.concatenate(collect(plain, 5)).max() == 0
    validation = trainer.make_vector_env(8, None, validation=True)
    assert not validation.track_coverage
    assert {g.tobytes() for g in validation.grids} == {g.tobytes() for g in validation_maps(10)}


# ---------------------------------------------------------------------- the study
def tiny_study_config(**settings) -> PoolConfig:
    tiny = dict(
        total_steps=1024,
        num_envs=16,
        batch_size=32,
        learning_starts=256,
        buffer_size=2048,
        eval_interval=512,
        eval_episodes=16,
        map_pool=30,
        validation_maps=8,
        seeds=[0],
        workers=1,
        max_steps=12,
    )
    return validated(PoolConfig(**map_pool_study.RECIPE | tiny | settings))


def test_tiny_study_end_to_end_and_reproducible(tmp_path: Path) -> None:
    out = tmp_path / "study"
    results = map_pool_study.run_study(tiny_study_config(), episodes=4, output_dir=out)
    files = sorted(p.name for p in out.iterdir())
    assert files == [
        "agent_models",
        "map_pool.csv",
        "map_pool.json",
        "map_pool.png",
        "timing.json",
        "training_logs",
    ]
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no staging left
    saved = json.loads((out / "map_pool.json").read_text(encoding="utf-8"))
    assert saved == json.loads(json.dumps(results))
    held_out = saved["held_out"]
    assert set(held_out["modes"]) == {"independent", "comm", "full"}
    for entry in held_out["modes"].values():
        assert entry["seeds"] == [0] and len(entry["eps"]["per_seed"]) == 1
    assert set(held_out["heuristics"]) == set(map_pool_study.HEURISTICS)
    for name in ("comm-independent", "full-comm", "full-independent"):  # paired by seed
        first, second = (held_out["modes"][m]["eps"]["mean"] for m in name.split("-"))
        assert held_out["differences"][name]["eps"]["mean"] == pytest.approx(first - second)
        assert held_out["differences"][name]["seeds"] == [0]
    heuristics = held_out["heuristics"]
    assert heuristics["oracle"]["mean"] > heuristics["random"]["mean"]
    run = saved["runs"]["full_seed0"]
    assert len(run["held_out_per_map"]["greedy"]) == len(HELD_OUT_MAP_SEEDS)
    assert run["held_out_mean"]["eps"] == pytest.approx(np.mean(run["held_out_per_map"]["eps"]))
    models = out / "agent_models"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        pair = [torch.jit.load(str(models / f"full_seed0_agent_{a}.pt")) for a in "AB"]
    x = torch.rand(5, 11)
    assert torch.equal(pair[0](x)[0], pair[1](x)[0])  # shared weights exported to both
    rows = (out / "map_pool.csv").read_text(encoding="utf-8").splitlines()
    assert len(rows) == 1 + 3 + len(map_pool_study.HEURISTICS)
    # The same run again: the same record and the same model bytes.
    again = map_pool_study.run_study(tiny_study_config(mode="full"), 4, tmp_path / "again")
    assert again["runs"]["full_seed0"] == results["runs"]["full_seed0"]
    for agent in "AB":
        name = f"full_seed0_agent_{agent}.pt"
        assert (models / name).read_bytes() == (
            tmp_path / "again" / "agent_models" / name
        ).read_bytes()


# ---------------------------------------------------------------------- the study's flags
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--num_seeds", "0"], "argument --num_seeds: must be an integer >= 1, got 0"),
        (["--map_pool", "0"], "argument --map_pool: must be an integer in 1..100000, got 0"),
        (["--map_pool", "-3"], "argument --map_pool: must be an integer in 1..100000, got -3"),
        (["--map_pool", "100001"], "argument --map_pool: must be an integer in 1..100000"),
        (
            ["--episodes_per_map", "0"],
            "argument --episodes_per_map: must be an integer in 1..100000",
        ),
        (["--total_steps", "0"], "argument --total_steps: must be an integer >= 1, got 0"),
        (["--workers", "0"], "argument --workers: must be an integer >= 1, got 0"),
        (["--mode", "comm,bogus"], "argument --mode: must be all or a comma-separated list"),
    ],
)
def test_study_flags_refuse_bad_values_naming_flag_and_range(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    with pytest.raises(SystemExit) as stop:
        map_pool_study.parse_args([*argv, "--output_dir", str(tmp_path / "out")])
    assert stop.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # refused before any work


def test_study_output_dir_must_not_be_a_file(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    file = tmp_path / "a_file"
    file.write_text("x", encoding="utf-8")
    with pytest.raises(SystemExit):
        map_pool_study.parse_args(["--output_dir", str(file)])
    assert "argument --output_dir: must be a folder, not a file" in capsys.readouterr().err


@pytest.mark.parametrize("folder", ["problem2", ".", "problem2/analysis"])
def test_a_study_never_replaces_a_folder_of_code(folder: str) -> None:
    """A study's output folder is replaced whole: one that is or holds code is refused
    before any staging folder is made."""
    root = Path(__file__).resolve().parents[2]
    output_dir = (root / folder).resolve()
    with pytest.raises(SystemExit, match="holds the project's code"), staged_output(output_dir):
        raise AssertionError("staged")
    assert not list(output_dir.parent.glob(f".{output_dir.name}.staging.*"))


def test_study_flags_become_the_recipe_with_seeds_from_zero(tmp_path: Path) -> None:
    cfg, args = map_pool_study.parse_args(
        ["--num_seeds", "2", "--map_pool", "1", "--mode", "full", "--output_dir", str(tmp_path)]
    )
    assert cfg.run_seeds() == [0, 1] and cfg.map_pool == 1 and cfg.run_modes() == ["full"]
    assert cfg.num_seeds == PoolConfig().num_seeds  # the count is stored as the seed list
    assert args.episodes_per_map == 500


def test_a_study_command_interrupted_with_ctrl_c_ends_in_one_line_and_status_130(
    capsys: pytest.CaptureFixture[str],
) -> None:
    def interrupted() -> None:
        raise KeyboardInterrupt

    with pytest.raises(SystemExit) as exit_info:
        run_command(interrupted)
    assert exit_info.value.code == 130
    assert capsys.readouterr().err == "interrupted (Ctrl-C)\n"
    assert run_command(lambda: 7) == 7  # otherwise the study's result passes through
