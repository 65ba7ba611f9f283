"""What the trainer learns from beyond the plain Double-DQN target: the potential-based
arrival term of the trained reward, advantage learning and its ramp, and the last weights
kept beside the selected checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.runs import load_policy
from multi_agent_env import MultiAgentEnv
from replay import sample_batch
from settings import TrainConfig
from vector_env import TARGET

from tests.conftest import load_problem_module

train = load_problem_module("problem2", "train")

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")


def trained(output_dir: Path, **settings: object) -> train.MultiAgentTrainer:
    """A trainer that has collected a little experience (no updates unless asked), writing
    its models and log into ``output_dir`` (never the committed results)."""
    cfg = TrainConfig(
        **{
            "mode": "independent",
            "total_steps": 640,
            "num_envs": 64,
            "batch_size": 32,
            "learning_starts": 10**9,
            "eval_interval": 10**9,
            "eval_episodes": 4,
            "keep_best": False,
            "output_dir": str(output_dir),
        }
        | settings,
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    trainer.train()
    return trainer


def observations(on_target: list[bool]) -> np.ndarray:
    """(1, 2, 11) observations whose patch centre shows the target where asked."""
    obs = np.zeros((1, 2, 11), dtype=np.float32)
    obs[0, :, 4] = [TARGET if on else 0 for on in on_target]
    return obs


@pytest.mark.parametrize(
    ("before", "after", "expected"),
    [
        ([False, False], [True, False], lambda g, phi: g * phi),  # an arrival
        ([True, False], [False, False], lambda g, phi: -phi),  # a departure
        ([True, False], [True, False], lambda g, phi: (g - 1) * phi),  # waiting on it
        ([True, False], [True, True], lambda g, phi: 2 * g * phi - phi),  # the partner joins
        ([False, False], [False, False], lambda g, phi: 0.0),
    ],
)
def test_arrival_term_is_gamma_phi_after_minus_phi_before(
    tmp_path: Path, before, after, expected
) -> None:
    trainer = trained(tmp_path, target_potential=4.0, potential_credit="team")
    info = {"on_target": np.array([after])}
    shaped = trainer.learning_rewards(np.array([-0.1]), info, observations(before))
    assert shaped[0] == pytest.approx(-0.1 + expected(trainer.cfg.gamma, 4.0))


def test_leaving_the_target_and_coming_back_earns_nothing_but_the_wait(tmp_path: Path) -> None:
    trainer = trained(tmp_path, target_potential=4.0, potential_credit="team")
    gamma, path = trainer.cfg.gamma, [True, False, True]  # on, off, back on
    terms = [
        trainer.learning_rewards(
            np.array([0.0]), {"on_target": np.array([[b, False]])}, observations([a, False])
        )[0]
        for a, b in zip(path[:-1], path[1:], strict=True)
    ]
    # Discounted from the first state: -Phi + gamma * gamma * Phi, only the two steps' delay.
    assert terms[0] + gamma * terms[1] == pytest.approx(-4.0 + gamma**2 * 4.0)
    assert trainer.learning_rewards(
        np.array([0.0]), {"on_target": np.array([[True, False]])}, observations([False, False])
    )[0] == pytest.approx(gamma * 4.0)  # every arrival pays, not only the first


def test_own_arrival_term_enters_each_agents_target_and_not_the_team_reward(
    tmp_path: Path,
) -> None:
    """potential_credit agent: the stored reward is the goal reward alone, and each agent's
    k-step target gains Φ (d · on(s') − on(s)) from its own observations only."""
    trainer = trained(tmp_path, target_potential=4.0, potential_credit="agent")
    info = {"on_target": np.array([[True, False]])}
    assert trainer.learning_rewards(np.array([-0.1]), info, observations([False, False]))[0] == -0.1
    batch = sample_batch(trainer.replay_buffer, 64, trainer.cfg.gamma)
    centre = trainer.env.obs_window**2 // 2
    batch.obs[0, :10, centre] = TARGET  # A on the target in the first rows' s, B in some s'
    batch.next_obs[1, 5:15, centre] = TARGET
    on_now = trainer.on_target(batch.obs).float()
    on_next = trainer.on_target(batch.next_obs).float()
    assert on_now.shape == (2, 64) and not torch.equal(on_now[0], on_now[1])  # agents differ
    _, delta_own, _ = trainer.td_loss(batch)
    trainer.cfg.target_potential = 0.0
    _, delta_plain, _ = trainer.td_loss(batch)
    # δ = Q(s, a) − y: a target higher by the agent's own term is a δ lower by as much.
    own_term = 4.0 * (batch.discount * on_next - on_now)
    assert torch.allclose(delta_plain - delta_own, own_term, atol=1e-5)


def test_without_a_potential_the_rewards_pass_unchanged(tmp_path: Path) -> None:
    trainer = trained(tmp_path, target_potential=0.0)
    info = {"on_target": np.array([[True, False]])}
    assert trainer.learning_rewards(np.array([-0.1]), info, observations([False, False]))[0] == -0.1


def test_advantage_learning_lowers_the_target_by_alpha_times_the_action_gap(tmp_path: Path) -> None:
    trainer = trained(tmp_path, advantage_learning=0.6, advantage_learning_ramp=0.5)
    assert trainer.progress() == 1.0 and trainer.advantage_learning_alpha() == pytest.approx(0.6)
    batch = sample_batch(trainer.replay_buffer, 32, trainer.cfg.gamma)
    _, delta_al, q_taken = trainer.td_loss(batch)
    trainer.cfg.advantage_learning = 0.0
    _, delta_plain, q_plain = trainer.td_loss(batch)
    assert torch.equal(q_taken, q_plain)
    with torch.no_grad():
        q_target = trainer.target(batch.obs * trainer.mask)[0]  # (2, B, 5)
    gap = q_target.max(dim=-1).values - q_target.gather(-1, batch.actions.unsqueeze(-1))[..., 0]
    assert (gap >= 0).all() and (gap > 0).any()
    # δ = Q(s, a) − y: a lower target by 0.6 · gap is a larger δ by the same amount.
    assert torch.allclose(delta_al - delta_plain, 0.6 * gap, atol=1e-5)


def test_alpha_rises_linearly_over_the_ramp_then_stays(tmp_path: Path) -> None:
    trainer = trained(tmp_path, advantage_learning=0.9, advantage_learning_ramp=0.25)
    for spent, expected in [(0, 0.0), (80, 0.9 * 0.5), (160, 0.9), (640, 0.9)]:
        trainer.env_steps = spent
        assert trainer.advantage_learning_alpha() == pytest.approx(expected)


def test_keep_best_saves_the_last_weights_beside_the_selected_ones(tmp_path: Path) -> None:
    cfg = TrainConfig(
        mode="full",
        total_steps=2048,
        num_envs=16,
        learning_starts=256,
        batch_size=32,
        eval_interval=512,
        eval_episodes=16,
        output_dir=str(tmp_path),
    )
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    trainer.train()
    last = load_policy(tmp_path / "agent_models" / "last_weights" / "full_seed641_agent_A.pt")
    selected = load_policy(tmp_path / "agent_models" / "full_seed641_agent_A.pt")
    probe = torch.rand(64, 11)
    trainer.online.load_state_dict(trainer.checkpoints[-1].state)  # the weights it ended with
    with torch.no_grad():
        assert torch.allclose(last(probe)[0], trainer.network_A(probe)[0], atol=1e-6)
        if trainer.best_checkpoint() is not trainer.checkpoints[-1]:
            assert not torch.allclose(selected(probe)[0], last(probe)[0])
