"""The hand-written TD gradient equals autograd on the readable loss (``td_loss``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from multi_agent_env import MultiAgentEnv
from paired_networks import FlatAdam, PairedQNetworks
from td_update import FastTDGradient, TransitionBatch
from train_config import TrainConfig

from tests.conftest import load_problem_module

train = load_problem_module("problem2", "train")


def trained_copies(tmp_path: Path, updates: int, **settings: object) -> list[tuple]:
    """Two identical trainers with a filled buffer; one updates with the hand-written
    gradient, one with autograd. Returns (losses, flat weights, TD errors) of each."""
    results = []
    for fast in (True, False):
        cfg = TrainConfig(
            seed=3, num_envs=16, total_steps=16 * 40, learning_starts=10**9, eval_interval=10**9,
            eval_episodes=4, keep_best=False, batch_size=32, output_dir=str(tmp_path), **settings,
        )  # fmt: skip
        trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
        trainer.train()  # fills the buffer: no update before learning_starts
        assert trainer.updates == 0 and trainer.fast_gradient is not None
        if not fast:
            trainer.fast_gradient = None
        losses = [trainer.update_networks(32) for _ in range(updates)]
        results.append((losses, trainer.online.flat.detach().clone(), trainer.last_td_errors))
    return results


@pytest.mark.parametrize(
    "settings",
    [
        {"mode": "independent"},
        {"mode": "comm"},
        {"mode": "full"},
        {"mode": "full", "comm_learning": "none"},
        {"mode": "full", "comm_noise": 0.0},
        {"mode": "full", "prioritized": True},
        {"mode": "comm", "max_grad_norm": 0.01},  # clipping on every update
        {"mode": "full", "max_grad_norm": 0.01, "prioritized": True},
        {"mode": "independent", "n_step": 3},
        {"mode": "full", "n_step": 3},
        {"mode": "comm", "n_step": 4, "max_grad_norm": 0.01, "prioritized": True},
    ],
)
def test_hand_written_gradient_equals_autograd(tmp_path: Path, settings: dict) -> None:
    (fast_losses, fast_weights, fast_td), (losses, weights, td) = trained_copies(
        tmp_path, 6, **settings
    )
    np.testing.assert_allclose(fast_losses, losses, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(fast_td, td, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(fast_weights, weights, rtol=1e-5, atol=1e-6)


def test_the_updates_change_the_weights_and_clipping_bounds_the_step(tmp_path: Path) -> None:
    """Guards the test above against comparing two updates that do nothing."""
    cfg = TrainConfig(
        mode="full", seed=3, num_envs=16, total_steps=640, learning_starts=10**9,
        eval_interval=10**9, eval_episodes=4, batch_size=32, output_dir=str(tmp_path),
        max_grad_norm=1e-3, lr=0.1,
    )  # fmt: skip
    trainer = train.MultiAgentTrainer(MultiAgentEnv(seed=641), cfg)
    trainer.train()
    before = trainer.online.flat.detach().clone()
    trainer.update_networks(32)
    assert trainer.online.flat.grad.norm() <= 1e-3 * (1 + 1e-5)
    assert not torch.equal(before, trainer.online.flat.detach())


def test_message_gradient_reaches_the_senders_head_only_with_dial() -> None:
    torch.manual_seed(0)
    online, target = PairedQNetworks(11, 16, 5), PairedQNetworks(11, 16, 5)
    batch = TransitionBatch.empty(8, 11)
    for tensor in (batch.obs, batch.next_obs, batch.last_obs, batch.prev_obs, batch.discount):
        tensor.uniform_()
    batch.has_prev.fill_(1.0)
    batch.actions.random_(0, 5)
    for dial in (True, False):
        gradient = FastTDGradient(
            online, target, torch.ones(11), dial, 1.0, torch.Generator().manual_seed(0)
        )
        gradient(batch)
        message_rows = online.gradients()[2][:, -1]
        assert (message_rows.abs().sum() > 0) == dial


def test_dueling_is_left_to_autograd() -> None:
    online = PairedQNetworks(11, 16, 5, dueling=True)
    with pytest.raises(ValueError, match="plain network"):
        FastTDGradient(online, online, torch.ones(11), True, 1.0, torch.Generator())


@pytest.mark.parametrize("fused", [True, False])
def test_flat_adam_steps_as_torch_adam_after_clipping(fused: bool) -> None:
    torch.manual_seed(0)
    networks = PairedQNetworks(4, 5, 3)
    flat = networks.flat
    with torch.no_grad():
        flat.copy_(torch.randn(flat.shape))
        reference = torch.nn.Parameter(flat.detach().clone())
    start = flat.detach().clone()
    torch_adam, flat_adam = torch.optim.Adam([reference], lr=1e-2), FlatAdam(flat, lr=1e-2)
    flat_adam.fused = fused
    for step in range(40):
        gradient = torch.randn(flat.shape) * (3.0 if step % 2 else 0.1)  # clipped every other
        reference.grad, flat.grad = gradient.clone(), gradient.clone()
        if step == 20:  # a learning-rate schedule changes the group's lr between steps
            torch_adam.param_groups[0]["lr"] = flat_adam.param_groups[0]["lr"] = 3e-3
        torch.nn.utils.clip_grad_norm_([reference], 5.0)
        flat_adam.step(grad_divisor=networks.clip_divisor(5.0))
        torch_adam.step()
        torch.testing.assert_close(flat.grad, reference.grad)  # the clipped gradient
    torch.testing.assert_close(flat.detach(), reference.detach(), rtol=1e-5, atol=1e-6)
    assert not torch.equal(flat.detach(), start)
