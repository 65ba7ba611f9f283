"""One-step memory on the map pool (studies/one_step/unseen.py): the pooled environment keeps
both extensions (a map drawn per episode, the previous observation and move), the pooled
learner exports memory-contract agents, the levers' summary pairs full with the right
independent runs, and the command line refuses what it cannot run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.map_sets import training_maps
from multi_agent_env import MultiAgentEnv
from studies.one_step import unseen
from studies.one_step.unseen import PooledOneStepEnv, PooledOneStepTrainer, recipe

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")

PREVIOUS, MOVE = slice(9, 20), slice(20, 25)
RAW = [*range(9), 25, 26]


def test_pooled_copies_draw_maps_and_remember_one_step() -> None:
    pool = training_maps(20, (10, 10))
    env = PooledOneStepEnv(8, map_pool=pool, seed=3, max_steps=4)
    obs = env.reset(seed=5)
    assert obs.shape == (8, 2, 27) and len(set(env.map_indices.tolist())) > 1
    rows, cols = env.positions[..., 0], env.positions[..., 1]
    assert (env.grids[env.map_indices[:, None], rows, cols] == 0).all()  # own map's free cells
    actions = np.random.default_rng(0).integers(0, 5, (8, 2))
    _, _, terminated, truncated, info = env.step(actions, np.zeros((8, 2)))
    np.testing.assert_array_equal(info["final_obs"][..., PREVIOUS], obs[..., RAW])
    np.testing.assert_array_equal(info["final_obs"][..., MOVE].argmax(-1), actions)
    assert not (terminated | truncated).any()


def test_pooled_learner_trains_and_exports_memory_agents(tmp_path: Path) -> None:
    cfg = recipe(mode="full", seed=0, map_pool=20, validation_maps=4, num_envs=8)
    cfg.output_dir = str(tmp_path)
    trainer = PooledOneStepTrainer(MultiAgentEnv(seed=641), cfg)
    assert trainer.obs_dim == 27 and trainer.cfg.share_weights
    for _ in range(40):
        trainer.collect(trainer.rollout)
    assert trainer.update_networks(32) > 0.0
    agent_a, _ = (torch.jit.load(str(p)) for p in trainer.save_models(tmp_path))
    h = agent_a.initial_state(3)
    q, message, h_next = agent_a(torch.rand(3, 11), torch.tensor([-1, 0, 4]), h)
    assert q.shape == (3, 5) and message.shape == (3, 1) and h_next.shape == (3, 11)


def lever_run(lever: str, mode: str, seed: int, best_eps: float) -> dict:
    rates = {"greedy": best_eps, "eps": best_eps}
    return {"lever": lever, "mode": mode, "seed": seed, "best": rates, "last": rates, "seconds": 1}


def test_levers_pair_full_with_the_independent_runs_the_lever_can_change() -> None:
    runs = []
    for seed, base in zip(unseen.TRAINING_SEEDS, (0.3, 0.5), strict=True):
        runs += [lever_run("recipe", "independent", seed, base)]
        runs += [lever_run("recipe", "full", seed, base + 0.1)]
        runs += [lever_run("twice_as_long", "independent", seed, base + 0.2)]
        runs += [lever_run("twice_as_long", "full", seed, base + 0.1)]
        runs += [lever_run("dial_noise_2", "full", seed, base + 0.3)]
    levers = unseen.summarise_levers(runs)["levers"]
    gaps = {
        name: entry["full_minus_independent_best_eps"]["mean"] for name, entry in levers.items()
    }
    assert gaps == pytest.approx({"recipe": 0.1, "twice_as_long": -0.1, "dial_noise_2": 0.3})
    assert levers["dial_noise_2"]["independent"]["best_eps"]["mean"] == pytest.approx(0.4)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--total_steps", "100"], "smoke runs"),
        (["--num_seeds", "6"], "--num_seeds must be in 1..5"),
        (["--workers", "0"], "--workers must be in 1..64"),
        (["--levers", "--total_steps", "100", "--output_dir", str(unseen.LEVERS_DIR)], "smoke"),
    ],
)
def test_command_line_refuses_before_any_work(
    argv: list[str], message: str, capsys: pytest.CaptureFixture
) -> None:
    with pytest.raises(SystemExit):
        unseen.parse_args(argv)
    assert message in capsys.readouterr().err
