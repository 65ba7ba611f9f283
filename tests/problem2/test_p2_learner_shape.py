"""The learner a reader follows: few calls from ``main`` to ``backward()``, the agent
network's forward written once, and a code version that documentation does not change."""

from __future__ import annotations

import traceback
from pathlib import Path

import models
import pytest
import torch

from tests.conftest import PROBLEM2, load_problem_module

train = load_problem_module("problem2", "train")

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")


def test_few_problem2_frames_stand_between_main_and_backward(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``python train.py`` with one worker (every call in one process): at each
    ``backward()`` at most 6 frames of problem2's code are on the stack, main's first."""
    stacks = []
    original = torch.autograd.backward

    def recorded(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        frames = traceback.extract_stack()
        stacks.append(
            [f.name for f in frames if Path(f.filename).resolve().is_relative_to(PROBLEM2)]
        )
        return original(*args, **kwargs)

    monkeypatch.setattr(torch.autograd, "backward", recorded)
    flags = ["--mode", "full", "--num_seeds", "1", "--workers", "1", "--total_steps", "2000"]
    flags += ["--learning_starts", "1000", "--eval_interval", "2000", "--eval_episodes", "4"]
    train.main([*flags, "--final_eval_episodes", "4", "--output_dir", str(tmp_path / "run")])
    assert stacks, "no backward() ran"
    for stack in stacks:
        assert stack[0] == "main" and stack[-1] == "update_networks", stack
        assert len(stack) <= 6, stack


def test_the_paired_networks_run_the_agent_networks_own_forward(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The training module has no forward math of its own: it calls AgentDQN's."""
    paired = models.PairedQNetworks(11, 16, 5, models.AgentDQN)
    x = torch.rand(2, 7, 11)
    q_values, logits = paired(x)
    for index in range(2):
        agent_q, agent_logit = paired.agent(index).forward_with_logit(x[index])
        assert torch.allclose(q_values[index], agent_q, atol=1e-6)
        assert torch.allclose(logits[index], agent_logit, atol=1e-6)

    def marked(self: models.AgentDQN, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return torch.full((*x.shape[:-1], 5), 7.0), torch.zeros(*x.shape[:-1], 1)

    monkeypatch.setattr(models.AgentDQN, "forward_with_logit", marked)
    assert torch.equal(paired(x)[0], torch.full((2, 7, 5), 7.0))
