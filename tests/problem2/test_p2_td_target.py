"""The learner's TD target, worked out by hand on a two-transition batch: the k-step return,
γ^k, the Double-DQN choice (online argmax, target value), a terminal transition that does not
bootstrap, a transition cut off by the time limit that does, and advantage learning."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from multi_agent_env import MultiAgentEnv
from replay import TransitionBatch
from settings import TrainConfig, validated
from torch import nn
from trainer import DQNTrainer

GAMMA = 0.9
# Q-values by state id (element 0 of the observation), one table per agent: (2, states, 5).
ONLINE = torch.tensor(
    [
        [[0, 0, 0, 0, 0], [1, 5, 2, 0, 0], [0, 0, 4, 1, 0], [2, 3, 1, 0, 0]],
        [[0, 0, 0, 0, 0], [0, 0, 0, 6, 1], [7, 0, 0, 0, 0], [0, 1, 4, 0, 0]],
    ],
    dtype=torch.float32,
)
TARGET = torch.tensor(
    [
        [[0, 0, 0, 0, 0], [10, 3, 20, 0, 0], [0, 9, 8, 0, 0], [1, 2, 6, 0, 0]],
        [[0, 0, 0, 0, 0], [0, 0, 0, -2, 30], [-1, 0, 0, 0, 0], [0, 5, 0, 0, 3]],
    ],
    dtype=torch.float32,
)


class Table(nn.Module):
    """A 'network' that looks its Q-values up by the state id: x (2, B, D) -> (2, B, 5)."""

    def __init__(self, table: torch.Tensor) -> None:
        super().__init__()
        self.table = table

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        ids = x[..., 0].long()
        q = torch.stack([self.table[agent][ids[agent]] for agent in range(2)])
        return q, torch.zeros(*x.shape[:-1], 1)


def observations(ids: list[int]) -> torch.Tensor:
    """(2, B, 11): both agents in the listed states (element 0 the id, the rest 0)."""
    obs = torch.zeros(2, len(ids), 11)
    obs[..., 0] = torch.tensor(ids, dtype=torch.float32)
    return obs


def hand_batch() -> TransitionBatch:
    """Transition 0 ends the episode (both on the target) after k = 1 step: R = 10, d = 0.
    Transition 1 is cut off by the time limit after k = 2 < n steps: R = -0.1 + γ (-0.1),
    d = γ², and it bootstraps from s'."""
    obs, next_obs = observations([3, 3]), observations([2, 1])
    return TransitionBatch(
        obs=obs,
        next_obs=next_obs,
        last_obs=obs,
        prev_obs=torch.zeros_like(obs),
        has_prev=torch.zeros(2),
        actions=torch.tensor([[0, 2], [1, 4]]),
        reward=torch.tensor([10.0, -0.1 + GAMMA * -0.1]),
        done=torch.tensor([1.0, 0.0]),
        discount=torch.tensor([0.0, GAMMA**2]),
    )


def trainer_with_tables(tmp_path: Path, advantage_learning: float) -> DQNTrainer:
    cfg = validated(
        TrainConfig(
            mode="independent",
            gamma=GAMMA,
            n_step=3,
            target_potential=0.0,
            advantage_learning=advantage_learning,
            advantage_learning_ramp=1.0,
            output_dir=str(tmp_path),
        )
    )
    trainer = DQNTrainer(MultiAgentEnv(seed=641), cfg)
    trainer.online, trainer.target = Table(ONLINE), Table(TARGET)
    trainer.env_steps = cfg.total_steps  # the end of the run: α at its full value
    return trainer


@pytest.mark.parametrize("alpha", [0.0, 0.5])
def test_td_target_matches_the_hand_computed_one(tmp_path: Path, alpha: float) -> None:
    trainer = trainer_with_tables(tmp_path, alpha)
    _, delta, q_taken = trainer.td_loss(hand_batch())
    # Q(s, a) of the online tables at s = state 3: A took 0 then 2, B took 1 then 4.
    assert q_taken.tolist() == [[2.0, 1.0], [1.0, 0.0]]
    # Transition 0, terminal: y = R = 10 for both agents (no bootstrap).
    # Transition 1, cut off: s' = state 1. Online argmax: A action 1 (5), B action 3 (6);
    # the target network values them: A 3 (not its max 20), B -2 (not its max 30).
    y = torch.tensor(
        [
            [10.0, -0.1 - 0.1 * GAMMA + GAMMA**2 * 3.0],
            [10.0, -0.1 - 0.1 * GAMMA + GAMMA**2 * -2.0],
        ]
    )
    # Advantage learning: minus α (max_b Q_target(s, b) − Q_target(s, a)) at s = state 3.
    # A: max 6; took 0 (1) and 2 (6). B: max 5; took 1 (5) and 4 (3).
    gaps = torch.tensor([[6.0 - 1.0, 6.0 - 6.0], [5.0 - 5.0, 5.0 - 3.0]])
    y = y - alpha * gaps
    assert torch.allclose(delta, q_taken - y, atol=1e-6)
