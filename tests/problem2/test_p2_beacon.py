"""The listener's training options (studies/one_step/beacon.py) and their screen: off, the
learner is the one-step map-pool learner; on, each changes only what learning sees, the
exported agent computes the distance's change itself, and the screen pairs full runs with the
independent runs that the same options could change."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.map_sets import training_maps
from multi_agent_env import MultiAgentEnv
from settings import SettingError
from studies.one_step import beacon_around, beacon_screen, beacon_study
from studies.one_step.beacon import (
    BeaconConfig,
    BeaconTrainer,
    DistanceChangeEnv,
)
from studies.one_step.unseen import PooledOneStepEnv, PooledOneStepTrainer, recipe

from tests.problem2.test_p2_one_step import assert_exported_agents_follow_the_network

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")

MODES = ("full", "independent")
REMEMBERED_DISTANCE = 19  # the previous copy's distance (9 + 10)
SMALL = dict(map_pool=20, validation_maps=4, num_envs=8, seed=0)


def config(tmp_path: Path, mode: str = "full", **options) -> BeaconConfig:
    fields = beacon_screen.map_pool_study.RECIPE | {"seeds": [], "workers": 1} | SMALL
    cfg = beacon_screen.validated(BeaconConfig(**fields | options, mode=mode))
    cfg.output_dir = str(tmp_path)
    return cfg


def collected(trainer, steps: int = 30) -> None:
    """``steps`` collection steps into the trainer's replay."""
    for _ in range(steps):
        trainer.collect(trainer.rollout)


def test_options_off_is_the_one_step_learner_step_for_step(tmp_path: Path) -> None:
    plain_cfg = recipe(mode="full", **SMALL)
    plain_cfg.output_dir = str(tmp_path / "plain")
    plain = PooledOneStepTrainer(MultiAgentEnv(seed=641), plain_cfg)
    options = BeaconTrainer(MultiAgentEnv(seed=641), config(tmp_path / "beacon"))
    for trainer in (plain, options):
        collected(trainer)
        trainer.update_networks(32)
    np.testing.assert_array_equal(plain.rollout.obs, options.rollout.obs)
    for p, q in zip(plain.online.parameters(), options.online.parameters(), strict=True):
        torch.testing.assert_close(p, q, rtol=0, atol=0)


def test_reverse_starts_put_one_agent_on_the_target_in_training_copies_only() -> None:
    env = PooledOneStepEnv(400, map_pool=training_maps(20, (10, 10)), seed=1, max_steps=3)
    env.start_on_target = 0.5
    env.reset(seed=2)
    on = (env.positions == env.target_positions[:, None]).all(-1)  # (N, 2)
    assert 0.4 < (on.sum(1) == 1).mean() < 0.6 and not (on.sum(1) == 2).any()
    trainer = BeaconTrainer(MultiAgentEnv(seed=641), config(Path("."), reverse_starts=1.0))
    assert trainer.rollout.env.start_on_target == 1.0
    assert trainer.make_vector_env(8, 0, validation=True).start_on_target == 0.0


def test_homing_shaping_is_gamma_phi_next_minus_phi(tmp_path: Path) -> None:
    trainer = BeaconTrainer(MultiAgentEnv(seed=641), config(tmp_path, homing_potential=2.0))
    obs = np.zeros((3, 2, 27), np.float32)
    obs[:, :, -1] = 0.5  # distance
    obs[0, 0, 4] = 2  # copy 0: A on the target; copy 1: none; copy 2: both
    obs[2, :, 4] = 2
    after = obs.copy()
    after[:, :, -1] = 0.25
    info = {"final_obs": after, "on_target": np.zeros((3, 2), bool)}
    base = PooledOneStepTrainer.learning_rewards(trainer, np.zeros(3), info, obs)
    shaped = trainer.learning_rewards(np.zeros(3), info, obs)
    gamma = trainer.cfg.gamma
    np.testing.assert_allclose(shaped - base, [gamma * 2 * 0.75 - 2 * 0.5, 0, 0], rtol=1e-6)


def test_distance_change_is_in_cells_and_zero_at_a_start() -> None:
    env = DistanceChangeEnv(6, map_pool=training_maps(20, (10, 10)), seed=1, max_steps=3)
    obs = env.reset(seed=4)
    assert (obs[..., REMEMBERED_DISTANCE] == 0).all()
    rng = np.random.default_rng(0)
    for _ in range(5):
        previous = obs[..., -1]
        actions = rng.integers(0, 5, (6, 2))
        obs, _, terminated, truncated, info = env.step(actions, np.zeros((6, 2)))
        change = (info["final_obs"][..., -1] - previous) * np.hypot(10, 10)
        np.testing.assert_allclose(info["final_obs"][..., REMEMBERED_DISTANCE], change, atol=1e-5)
        restarted = terminated | truncated
        assert (obs[restarted][..., REMEMBERED_DISTANCE] == 0).all()


def test_exported_agent_computes_the_distance_change_itself(tmp_path: Path) -> None:
    trainer = BeaconTrainer(MultiAgentEnv(seed=641), config(tmp_path, distance_change=True))
    torch.manual_seed(1)
    with torch.no_grad():
        for p in trainer.online.parameters():
            p.add_(0.3 * torch.randn_like(p))
    agents = [torch.jit.load(str(p)) for p in trainer.save_models(tmp_path / "m")]
    env = DistanceChangeEnv(5, map_pool=training_maps(20, (10, 10)), seed=2, max_steps=4)
    assert_exported_agents_follow_the_network(trainer, agents, env, tolerance=1e-5)


def test_listening_loss_rewards_a_policy_that_depends_on_the_message(tmp_path: Path) -> None:
    trainer = BeaconTrainer(MultiAgentEnv(seed=641), config(tmp_path, listening=0.5))
    collected(trainer, 20)
    batch = trainer.sample(64)
    noise = trainer.noise_rng.get_state()  # DIAL's noise: the same draws for both losses
    loss, *_ = trainer.td_loss(batch)
    trainer.noise_rng.set_state(noise)
    plain, *_ = PooledOneStepTrainer.td_loss(trainer, batch)
    obs = batch.obs * trainer.mask
    unheard = obs.clone()
    unheard[..., -2] = obs[..., -2].mean(dim=1, keepdim=True)
    with torch.no_grad():
        p, q = (trainer.online(x)[0].softmax(-1) for x in (obs, unheard))
    expected = plain - 0.5 * (p - q).abs().sum(-1).mean(1).sum()
    torch.testing.assert_close(loss, expected)
    independent = BeaconTrainer(
        MultiAgentEnv(seed=641), config(tmp_path, mode="independent", listening=0.5)
    )
    collected(independent, 20)
    batch = independent.sample(64)
    torch.testing.assert_close(
        independent.td_loss(batch)[0], PooledOneStepTrainer.td_loss(independent, batch)[0]
    )


@pytest.mark.parametrize(
    "option, value, message",
    [
        ("reverse_starts", 1.5, "reverse_starts"),
        ("homing_potential", -1.0, "homing_potential"),
        ("listening", float("nan"), "listening"),
        ("distance_change", 1, "distance_change"),
    ],
)
def test_bad_options_are_refused_by_name(option: str, value, message: str) -> None:
    with pytest.raises(SettingError, match=message):
        config(Path("."), **{option: value})


def test_screen_pairs_full_with_the_independent_runs_of_the_same_changes() -> None:
    cells = beacon_screen.screen_cells()
    assert cells["RHD"]["changes"] == {
        "reverse_starts": 0.5,
        "homing_potential": 2.0,
        "distance_change": True,
    }
    assert cells["RHD"]["modes"] == ["full"] and cells["RH"]["modes"] == ["full", "independent"]
    assert beacon_screen.independent_twin("RHD", cells) == "RH"
    assert beacon_screen.independent_twin("D", cells) == "none"
    assert beacon_screen.independent_twin("RHD+listening", cells) is None
    runs = []
    for cell, spec in cells.items():
        for mode in spec["modes"]:
            for seed in beacon_screen.TRAINING_SEEDS:
                score = 0.5 if (cell, mode) == ("HD", "full") else 0.3
                score += 0.2 if (cell, mode) == ("R", "independent") else 0.0
                rates = {"eps": score, "greedy": score}
                runs.append(
                    {"cell": cell, "mode": mode, "seed": seed, "best": rates, "last": rates}
                    | {"best_env_steps": 1, "seconds": 1.0}
                )
    summary = beacon_screen.summarise(runs, cells)
    assert summary["winner"] == "HD"
    assert summary["cells"]["HD"]["full_minus_independent_eps"]["mean"] == pytest.approx(0.2)
    assert beacon_screen.best_independent(summary["cells"]) == "R"


def test_a_tiny_run_with_every_option_reproduces_its_bytes(tmp_path: Path) -> None:
    files = []
    for name in ("first", "second"):
        options = dict(reverse_starts=0.5, homing_potential=2.0, distance_change=True)
        cfg = config(tmp_path / name, listening=0.1, total_steps=2000, learning_starts=300)
        cfg.eval_interval, cfg.eval_episodes, cfg.batch_size = 1000, 4, 32
        for key, value in options.items():
            setattr(cfg, key, value)
        trainer = BeaconTrainer(MultiAgentEnv(seed=641), cfg)
        trainer.train()
        assert trainer.updates > 0
        folder = tmp_path / name / "agent_models"
        files.append({p.name: p.read_bytes() for p in sorted(folder.glob("*.pt"))})
    assert sorted(files[0]) == ["full_seed0_agent_A.pt", "full_seed0_agent_B.pt"]
    assert files[0] == files[1]


def test_the_distance_change_leaves_independent_agents_as_they_are(tmp_path: Path) -> None:
    """Why the second stage's independent runs of a cell with D are the twins of its full
    runs: masked out, the distance's change trains the same weights as the raw distance."""
    weights = []
    for name, options in (("raw", {}), ("change", {"distance_change": True})):
        cfg = config(tmp_path / name, "independent", homing_potential=2.0, **options)
        cfg.total_steps, cfg.learning_starts, cfg.batch_size = 1200, 300, 32
        cfg.eval_interval, cfg.eval_episodes = 600, 4
        trainer = BeaconTrainer(MultiAgentEnv(seed=641), cfg)
        trainer.train()
        assert trainer.updates > 0
        weights.append([p.detach().clone() for p in trainer.online.parameters()])
    for raw, change in zip(*weights, strict=True):
        torch.testing.assert_close(raw, change, rtol=0, atol=0)


def test_the_second_stage_varies_the_first_winner_and_judges_both_stages_together() -> None:
    hd = beacon_screen.screen_cells()["HD"]["changes"]
    cells = beacon_around.around("HD", hd)
    assert list(cells) == ["HD k=1", "HD k=4", "HD R=0.25", "HD 2M"]
    assert cells["HD k=4"]["changes"] == hd | {"homing_potential": 4.0}
    assert cells["HD 2M"]["changes"] == hd | {"total_steps": 2_000_000}
    assert all(spec["modes"] == ["full", "independent"] for spec in cells.values())
    rhd = beacon_screen.screen_cells()["RHD"]["changes"]
    assert [c for c in beacon_around.around("RHD", rhd) if "R=" in c] == [
        "RHD R=0.25",
        "RHD R=0.75",
    ]
    assert list(beacon_around.around("D", {"distance_change": True})) == ["D R=0.25", "D 2M"]
    first = {
        "winner": "HD",
        "cells": {"HD": {"full": {"eps": {"mean": 0.48}}, "modes": ["full"]}}
        | {"RH": {"modes": ["full", "independent"]} | {m: {"eps": {"mean": 0.55}} for m in MODES}},
    }
    runs = []
    for cell, spec in cells.items():
        for mode in spec["modes"]:
            for seed in beacon_screen.TRAINING_SEEDS:
                score = {"HD 2M": 0.6, "HD k=1": 0.4}.get(cell, 0.3) - 0.1 * (mode != "full")
                rates = {"eps": score, "greedy": score}
                runs.append({"cell": cell, "mode": mode, "seed": seed, "best": rates})
                runs[-1]["best_env_steps"] = 1
    summary = beacon_around.summarise(runs, first, cells)
    assert list(summary["cells"]) == ["HD", "RH", *cells]
    assert summary["winner"] == "HD 2M" and summary["best_independent"] == "RH"
    assert summary["cells"]["HD 2M"]["independent_from"] == "HD 2M"
    assert summary["cells"]["HD 2M"]["full_minus_independent_eps"]["mean"] == pytest.approx(0.1)


def test_the_second_stage_refuses_smoke_runs_into_its_results() -> None:
    with pytest.raises(SystemExit):
        beacon_around.parse_args(["--total_steps", "100"])


@pytest.mark.parametrize("module", [beacon_screen, beacon_around, beacon_study])
def test_a_smoke_budget_without_an_update_is_refused_before_any_run(
    module, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        module.parse_args(["--total_steps", "3000", "--output_dir", str(tmp_path / "out")])
    assert "--total_steps: must be at least learning_starts" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
