"""The trainer used the way the course skeleton uses it: a Namespace of the skeleton's
flags, transitions pushed by hand, any odd window and grid, files written by train()."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.runs import load_policy
from models import export_policy, observation_mask
from multi_agent_env import MultiAgentEnv
from rollout import VALIDATION_SEED, select_best
from settings import TrainConfig, validated
from studies.staging import best_env_steps, best_selection

from tests.conftest import load_problem_module, weights_of

train = load_problem_module("problem2", "train")

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")


def skeleton_args(**changes: object) -> argparse.Namespace:
    """Exactly the flags of the course skeleton's train.py."""
    flags = dict(
        grid_size=[10, 10],
        max_steps=50,
        num_episodes=4,
        batch_size=32,
        lr=1e-3,
        gamma=0.99,
        epsilon_start=1.0,
        epsilon_end=0.05,
        epsilon_decay=0.995,
        hidden_dim=64,
        target_update=100,
        mode="full",
        seed=641,
        save_freq=100,
    )
    return argparse.Namespace(**(flags | changes))


@pytest.mark.parametrize("mode", [None, "all", "full"])
def test_skeleton_namespace_trains_full_and_decays_epsilon_per_episode(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, mode: str | None
) -> None:
    monkeypatch.chdir(tmp_path)
    args = skeleton_args(mode=mode)
    if mode is None:
        del args.mode
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), args)
    assert trainer.mode == "full" and trainer.cfg.epsilon_decay == 0.995
    reward, success = trainer.train_episode()
    assert type(reward) is float and type(success) is bool
    assert trainer.epsilon == pytest.approx(0.995)
    trainer.train_episode()
    assert trainer.epsilon == pytest.approx(0.995**2)
    trainer.train()  # 4 episodes, then it saves under results/ of the current folder
    assert trainer.episodes >= 4 and trainer.epsilon == pytest.approx(
        max(0.05, 0.995**trainer.episodes)
    )
    for agent in "AB":
        assert (tmp_path / "results" / "agent_models" / f"full_seed641_agent_{agent}.pt").is_file()
    assert (tmp_path / "results" / "training_logs" / "full_seed641.csv").is_file()


def test_linear_epsilon_over_epsilon_fraction(tmp_path: Path) -> None:
    cfg = TrainConfig(
        mode="comm",
        total_steps=6400,
        num_envs=64,
        epsilon_fraction=0.25,
        learning_starts=10**9,
        eval_interval=10**9,
        eval_episodes=4,
        output_dir=str(tmp_path),
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    trainer.env_steps = 800  # half of the first quarter
    assert trainer.next_epsilon(0) == pytest.approx(1.0 - 0.5 * 0.95)
    trainer.env_steps = 1600
    assert trainer.next_epsilon(3) == pytest.approx(0.05)


def test_epsilon_decay_outside_its_range_is_refused_with_its_meaning() -> None:
    with pytest.raises(ValueError, match="multiplicative factor per episode"):
        validated(TrainConfig(epsilon_decay=1.5))


def push_by_hand(trainer: train.MultiAgentTrainer, count: int, rng: np.random.Generator) -> None:
    """Push ``count`` random one-step transitions with the skeleton's ten fields."""
    for _ in range(count):
        state_a, state_b, next_a, next_b = rng.random((4, 11), dtype=np.float32)
        trainer.replay_buffer.push(
            state_a,
            state_b,
            int(rng.integers(5)),
            int(rng.integers(5)),
            rng.random(),
            rng.random(),
            -0.1,
            next_a,
            next_b,
            False,
        )


def assert_hard_copy_after(trainer: train.MultiAgentTrainer, period: int) -> None:
    """The target stays as it is for ``period`` - 1 updates, then equals the online."""
    start = weights_of(trainer.target)
    for _ in range(period - 1):
        trainer.update_networks(trainer.cfg.batch_size)
        assert torch.equal(weights_of(trainer.target), start)
    trainer.update_networks(trainer.cfg.batch_size)
    assert trainer.updates == period
    assert torch.equal(weights_of(trainer.target), weights_of(trainer.online))


def filled_trainer(**settings: object) -> train.MultiAgentTrainer:
    """A full-mode trainer whose buffer holds more than a batch, with no update yet."""
    cfg = TrainConfig(
        mode="full",
        total_steps=640,
        num_envs=64,
        batch_size=32,
        learning_starts=10**9,
        eval_interval=10**9,
        eval_episodes=4,
        keep_best=False,
        **settings,
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    trainer.train()
    return trainer


def test_soft_target_update_moves_the_target_tau_of_the_way_after_each_update(
    tmp_path: Path,
) -> None:
    trainer = filled_trainer(target_tau=0.25, output_dir=str(tmp_path))
    assert trainer.cfg.target_update == 0  # the default: soft updates
    for _ in range(3):
        before = weights_of(trainer.target)
        trainer.update_networks(trainer.cfg.batch_size)
        online = weights_of(trainer.online)
        assert not torch.equal(online, before)
        assert torch.equal(weights_of(trainer.target), before.lerp(online, 0.25))


def test_target_update_makes_hard_copies_every_that_many_updates(tmp_path: Path) -> None:
    assert_hard_copy_after(filled_trainer(target_update=3, output_dir=str(tmp_path)), 3)


def test_the_skeletons_target_update_means_hard_copies() -> None:
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), skeleton_args(target_update=7))
    push_by_hand(trainer, 32, np.random.default_rng(0))  # one batch of the skeleton's size
    assert trainer.cfg.target_update == 7
    assert_hard_copy_after(trainer, 7)


@pytest.mark.parametrize("target_update", [0, 5])
def test_no_target_update_while_the_buffer_holds_less_than_a_batch(
    tmp_path: Path, target_update: int
) -> None:
    cfg = TrainConfig(
        mode="full",
        batch_size=32,
        target_update=target_update,
        output_dir=str(tmp_path),
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    with torch.no_grad():
        for parameter in trainer.target.parameters():  # a target unlike the online networks
            parameter.add_(1.0)
    target = weights_of(trainer.target)
    trainer.update_networks(trainer.cfg.batch_size)
    assert trainer.updates == 0 and torch.equal(weights_of(trainer.target), target)


@pytest.mark.parametrize("mode", ["independent", "comm", "full"])
def test_transitions_pushed_by_hand_train_in_every_mode(mode: str) -> None:
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), skeleton_args(mode=mode))
    rng = np.random.default_rng(0)
    push_by_hand(trainer, 31, rng)
    assert trainer.update_networks(32) == 0.0 and trainer.updates == 0
    push_by_hand(trainer, 1, rng)
    before = weights_of(trainer.online)
    loss = trainer.update_networks(32)
    assert type(loss) is float and loss > 0 and trainer.updates == 1
    assert not torch.equal(before, weights_of(trainer.online))
    trainer.train_episode()  # the trainer's own transitions join the hand-filled buffer


@pytest.mark.parametrize(("window", "grid"), [(5, (7, 9)), (7, (6, 6))])
def test_any_odd_window_and_grid(tmp_path: Path, window: int, grid: tuple[int, int]) -> None:
    env = MultiAgentEnv(grid_size=grid, obs_window=window, seed=3)
    cfg = TrainConfig(
        mode="full",
        total_steps=1024,
        num_envs=16,
        learning_starts=256,
        batch_size=32,
        eval_interval=512,
        eval_episodes=8,
        output_dir=str(tmp_path),
    )
    trainer = train.MultiAgentTrainer(env, cfg)
    trainer.train()
    obs_dim = window**2 + 2
    assert trainer.obs_dim == obs_dim and trainer.updates > 0
    policy = load_policy(tmp_path / "agent_models" / "full_seed641_agent_A.pt")
    q_values, comm = policy(torch.rand(3, obs_dim))
    assert q_values.shape == (3, 5) and comm.shape == (3, 1)
    # The masks follow the window: message at w², distance at w² + 1.
    for mode, zeroed in (("independent", [obs_dim - 2, obs_dim - 1]), ("comm", [obs_dim - 1])):
        assert np.flatnonzero(observation_mask(mode, obs_dim) == 0).tolist() == zeroed
    masked = train.apply_observation_mask(np.ones((2, obs_dim), np.float32), "independent")
    assert masked[:, -2:].sum() == 0 and masked[:, :-2].sum() == 2 * (obs_dim - 2)
    network = trainer.network_A
    exported = load_policy(export_policy(network, "comm", tmp_path / "comm.pt"))
    x = torch.rand(4, obs_dim)
    changed = x.clone()
    changed[:, -1] += 1.0  # the distance is hidden from comm
    torch.testing.assert_close(exported(x)[0], exported(changed)[0])


def test_train_writes_models_and_appends_the_log_as_it_goes(tmp_path: Path) -> None:
    cfg = TrainConfig(
        mode="comm",
        seed=5,
        total_steps=1536,
        num_envs=16,
        learning_starts=512,
        batch_size=32,
        eval_interval=512,
        eval_episodes=8,
        output_dir=str(tmp_path / "out"),
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    seen_rows = []

    def progress(row: dict) -> None:  # the file holds every row reported so far
        with open(trainer.log_path, encoding="utf-8") as handle:
            seen_rows.append(len(list(csv.DictReader(handle))))

    log = trainer.train(progress)
    assert seen_rows == list(range(1, len(log) + 1))
    with open(tmp_path / "out" / "training_logs" / "comm_seed5.csv", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(row["env_steps"]) for row in rows] == [row["env_steps"] for row in log]
    for agent in "AB":
        assert (tmp_path / "out" / "agent_models" / f"comm_seed5_agent_{agent}.pt").is_file()


@pytest.mark.parametrize("select_by", ["steps", "success", "return"])
def test_training_ends_with_the_checkpoint_that_select_by_picks_from_the_log(
    tmp_path: Path, select_by: str
) -> None:
    cfg = TrainConfig(
        mode="full",
        total_steps=2048,
        num_envs=16,
        learning_starts=256,
        batch_size=32,
        eval_interval=512,
        eval_episodes=16,
        select_by=select_by,
        output_dir=str(tmp_path),
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    log = trainer.train()

    def summary(row: dict, condition: str) -> dict:
        steps = row[f"eval_steps_{condition}"]
        return {
            "success_rate": row[f"eval_success_{condition}"],
            "mean_steps_to_success": None if np.isnan(steps) else steps,
            "mean_return": row[f"eval_return_{condition}"],
        }

    best = log[select_best([(summary(r, "greedy"), summary(r, "eps")) for r in log], select_by)]
    assert best_env_steps(trainer) == best["env_steps"]
    assert best_selection(trainer) == {
        "greedy": best["eval_success_greedy"],
        "eps": best["eval_success_eps"],
    }
    # The weights the run ends with are that checkpoint's: they replay its validation result.
    again = trainer.evaluation_summary(cfg.eval_episodes, 0.0, VALIDATION_SEED)
    assert again["success_rate"] == best["eval_success_greedy"]
    assert again["mean_return"] == pytest.approx(best["eval_return_greedy"])


def test_select_by_is_refused_outside_its_choices() -> None:
    with pytest.raises(ValueError, match="select_by"):
        validated(TrainConfig(select_by="luck"))
