"""One-step memory agents (studies/one_step): the 27-dim observations, the mask in both
copies, the exported file under the memory contract computing what the training network
computes, and a tiny batch that trains, exports and reproduces its files byte for byte."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import train
from rollout import run_episodes
from settings import TrainConfig
from studies.memory.agents import memory_policy
from studies.one_step import why
from studies.one_step.agents import (
    OneStepMemoryEnv,
    OneStepMemoryTrainer,
    augment,
    memory_mask,
)
from studies.one_step.panel import memory_pair_policy
from vector_env import VectorMultiAgentEnv

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")

PATCH, PREVIOUS, MOVE = slice(0, 9), slice(9, 20), slice(20, 25)
RAW = [*range(9), 25, 26]  # the current observation inside the 27 inputs
MEMORY_KEEPS = (("observation", "move"), ("move",), ("observation",))


def test_observations_hold_the_previous_observation_and_move() -> None:
    env = OneStepMemoryEnv(6, seed=4, max_steps=3)
    raw_env = VectorMultiAgentEnv(6, seed=4, max_steps=3)
    obs, raw = env.reset(seed=1), raw_env.reset(seed=1)
    assert env.obs_dim == 27 and obs.shape == (6, 2, 27) and obs.dtype == np.float32
    assert not obs[..., PREVIOUS].any() and not obs[..., MOVE].any()
    np.testing.assert_array_equal(obs[..., RAW], raw)
    np.testing.assert_array_equal(env.current_observations(), obs)
    rng = np.random.default_rng(0)
    for step in range(1, 6):
        actions = rng.integers(0, 5, (6, 2))
        messages = rng.random((6, 2)).astype(np.float32)
        next_obs, _, terminated, truncated, info = env.step(actions, messages)
        next_raw, *_, raw_info = raw_env.step(actions, messages)
        final = info["final_obs"]
        assert final.shape == next_obs.shape == (6, 2, 27)
        np.testing.assert_array_equal(final[..., RAW], raw_info["final_obs"])
        np.testing.assert_array_equal(final[..., PREVIOUS], raw)  # o_{t-1}: before the step
        np.testing.assert_array_equal(final[..., MOVE].argmax(-1), actions)
        np.testing.assert_array_equal(final[..., MOVE].sum(-1), 1.0)
        restarted = terminated | truncated
        assert restarted.any() == (step % 3 == 0)  # max_steps 3 cuts every episode off
        np.testing.assert_array_equal(next_obs[~restarted], final[~restarted])
        np.testing.assert_array_equal(next_obs[..., RAW], next_raw)
        assert not next_obs[restarted][..., PREVIOUS].any()
        assert not next_obs[restarted][..., MOVE].any()
        np.testing.assert_array_equal(env.current_observations(), next_obs)
        obs, raw = next_obs, next_raw
    with pytest.raises(ValueError):
        env.step(np.full((6, 2), 7), np.zeros((6, 2)))
    np.testing.assert_array_equal(env.current_observations(), obs)  # memory kept


def test_augment_puts_message_and_distance_last() -> None:
    raw = np.arange(22, dtype=np.float32).reshape(1, 2, 11)
    out = augment(raw, raw + 100, np.array([[-1, 4]]))
    assert out.shape == (1, 2, 27)
    np.testing.assert_array_equal(out[0, 0, 25:], [9, 10])
    np.testing.assert_array_equal(out[0, 0, 9:20], raw[0, 0] + 100)
    np.testing.assert_array_equal(out[..., MOVE], [[[0] * 5, [0, 0, 0, 0, 1]]])


def small_config(mode: str, output_dir: Path, **kw: object) -> TrainConfig:
    settings = dict(
        mode=mode,
        map_seed=4,
        num_seeds=1,
        total_steps=3000,
        learning_starts=500,
        num_envs=8,
        eval_episodes=10,
        final_eval_episodes=10,
        batch_size=32,
        output_dir=str(output_dir),
        workers=1,
    )
    return TrainConfig(**(settings | kw))


def make_trainer(mode: str, tmp_path: Path) -> OneStepMemoryTrainer:
    env = VectorMultiAgentEnv(1, seed=4)
    return OneStepMemoryTrainer(env, small_config(mode, tmp_path))


@pytest.mark.parametrize(
    ("mode", "hidden", "dial"),
    [
        ("independent", (18, 19, 25, 26), False),
        ("comm", (19, 26), True),
        ("distance", (18, 25), False),
        ("full", (), True),
    ],
)
def test_mask_hides_the_mode_channels_in_both_copies(
    mode: str, hidden: tuple[int, ...], dial: bool, tmp_path: Path
) -> None:
    assert tuple(np.flatnonzero(memory_mask(mode) == 0)) == hidden
    trainer = make_trainer(mode, tmp_path)
    assert trainer.obs_dim == 27 and trainer.mask.shape == (27,)
    torch.testing.assert_close(trainer.mask, torch.from_numpy(memory_mask(mode)))
    assert trainer.dial == dial and int(trainer.message_column.nonzero()) == 25


@pytest.mark.parametrize("mode", ["comm", "distance"])
def test_exported_policy_equals_the_training_network(mode: str, tmp_path: Path) -> None:
    trainer = make_trainer(mode, tmp_path)
    torch.manual_seed(1)
    with torch.no_grad():  # weights away from the initial ones, messages away from 0.5
        for p in trainer.online.parameters():
            p.add_(0.3 * torch.randn_like(p))
    paths = trainer.save_models(tmp_path / "models")
    assert [p.name for p in paths] == [f"{mode}_seed641_agent_{a}.pt" for a in "AB"]
    agents = [torch.jit.load(str(p)) for p in paths]
    env = OneStepMemoryEnv(5, grid=trainer.env.grid, max_steps=4)
    assert_exported_agents_follow_the_network(trainer, agents, env, tolerance=1e-6)


def assert_exported_agents_follow_the_network(
    trainer, agents: list, env: OneStepMemoryEnv, tolerance: float
) -> None:
    """Play 10 steps of ``env`` (5 copies, through its auto-resets) with random moves and
    messages; at each step each exported agent, fed the raw observation, the move made and
    its own state, gives the Q-values of the trainer's network on the inputs ``env`` built."""
    obs = env.reset(seed=3)
    states = [agent.initial_state(5) for agent in agents]
    previous = torch.full((5, 2), -1)
    rng = np.random.default_rng(2)
    for _ in range(10):
        starting = torch.from_numpy(env.steps == 0)
        with torch.no_grad():
            q_train, _ = trainer.online(torch.from_numpy(obs).transpose(0, 1) * trainer.mask)
            raw = torch.from_numpy(obs[..., RAW])
            for i, agent in enumerate(agents):
                h = torch.where(starting[:, None], agent.initial_state(5), states[i])
                prev = torch.where(starting, -1, previous[:, i])
                q, message, states[i] = agent(raw[:, i], prev, h)
                assert q.shape == (5, 5) and message.shape == (5, 1)
                torch.testing.assert_close(q, q_train[i], rtol=tolerance, atol=tolerance)
        actions = rng.integers(0, 5, (5, 2))  # exploration: the moves actually made
        previous = torch.from_numpy(actions)
        obs, *_ = env.step(actions, rng.random((5, 2)))


def test_memory_policy_runs_the_exported_pair(tmp_path: Path) -> None:
    trainer = make_trainer("full", tmp_path)
    agents = [torch.jit.load(str(p)) for p in trainer.save_models(tmp_path / "m")]
    env = VectorMultiAgentEnv(20, grid=trainer.env.grid)
    results = run_episodes(env, memory_policy(tuple(agents), env, 0.05, seed=0), 20, seed=5)
    assert results.successes.shape == (20,)


def test_tiny_batch_trains_exports_and_reproduces_bytes(tmp_path: Path) -> None:
    files = {}
    for name in ("first", "second"):  # 1200 steps: updates from step 500 on, as with more
        cfg = small_config("independent,full", tmp_path / name, total_steps=1200)
        finals = train.main(cfg=cfg, trainer_class=OneStepMemoryTrainer)
        assert [(f["mode"], f["seed"]) for f in finals] == [("independent", 641), ("full", 641)]
        models = tmp_path / name / "agent_models"
        files[name] = {p.name: p.read_bytes() for p in sorted(models.glob("*_seed*.pt"))}
    assert sorted(files["first"]) == [
        f"{m}_seed641_agent_{a}.pt" for m in ("full", "independent") for a in "AB"
    ]
    assert files["first"] == files["second"]
    model = torch.jit.load(str(tmp_path / "first" / "agent_models" / "full_seed641_agent_B.pt"))
    h = model.initial_state(3)
    q, message, h_next = model(torch.rand(3, 11), torch.tensor([-1, 0, 4]), h)
    assert h.shape == (3, 11) and q.shape == (3, 5) and message.shape == (3, 1)
    assert h_next.shape == (3, 11) and ((message >= 0) & (message <= 1)).all()


def test_panel_policy_is_memory_policy_when_greedy_and_explores_with_the_panel_draws(
    tmp_path: Path,
) -> None:
    trainer = make_trainer("comm", tmp_path)
    agents = tuple(torch.jit.load(str(p)) for p in trainer.save_models(tmp_path / "m"))
    runs = {}
    for name, epsilon in (("greedy", 0.0), ("eps", 0.5)):
        env = VectorMultiAgentEnv(30, grid=trainer.env.grid)
        runs[name] = run_episodes(env, memory_pair_policy(agents, env, epsilon), 30, seed=9)
    env = VectorMultiAgentEnv(30, grid=trainer.env.grid)
    reference = run_episodes(env, memory_policy(agents, env, 0.0), 30, seed=9)
    np.testing.assert_array_equal(runs["greedy"].lengths, reference.lengths)
    np.testing.assert_array_equal(runs["greedy"].returns, reference.returns)
    assert not np.array_equal(runs["eps"].returns, reference.returns)


def test_ablation_masks_zero_exactly_the_memory_part_left_out() -> None:
    both, move, observation = (memory_mask("full", 11, keep) for keep in MEMORY_KEEPS)
    np.testing.assert_array_equal(both[PREVIOUS], 1.0)
    np.testing.assert_array_equal(move[PREVIOUS], 0.0)
    np.testing.assert_array_equal(move[MOVE], 1.0)
    np.testing.assert_array_equal(observation[MOVE], 0.0)
    np.testing.assert_array_equal(observation[PREVIOUS], 1.0)
    for mask in (both, move, observation):
        np.testing.assert_array_equal(mask[RAW], 1.0)  # the current observation untouched


class EchoAgent:
    """Returns what it was fed: Q from the previous move, h as the message."""

    def initial_state(self, n: int) -> torch.Tensor:
        return torch.zeros(n, 11)

    def __call__(self, obs: torch.Tensor, prev: torch.Tensor, h: torch.Tensor) -> tuple:
        return prev.float()[:, None].expand(-1, 5), h[:, :1], h


def test_interventions_replace_only_the_named_memory_input() -> None:
    prev = torch.tensor([-1, 0, 2, 3])
    h = torch.arange(44, dtype=torch.float32).reshape(4, 11)
    obs = torch.zeros(4, 11)

    def fed(kind: str) -> tuple[torch.Tensor, torch.Tensor]:
        q, message, _ = why.Intervened(EchoAgent(), kind, seed=0)(obs, prev, h)
        return q[:, 0].long(), message[:, 0]

    moves, states = fed("move_other_episode")
    assert moves.tolist() == [-1, 0, 0, 2]  # copy 1's partner episode is starting: its own kept
    assert torch.equal(states, h[:, 0])
    moves, states = fed("observation_other_episode")
    assert moves.tolist() == prev.tolist()
    assert states.tolist() == [0.0, 0.0, 11.0, 22.0]  # at an episode start h stays
    moves, _ = fed("move_random")
    assert moves[0] == -1 and ((moves[1:] >= 0) & (moves[1:] < 5)).all()
    _, states = fed("zeros")
    assert not states.any()


def test_move_shares_count_moves_that_undo_or_repeat_the_previous_one() -> None:
    grid = np.zeros((3, 3), dtype=np.int64)
    grid[2, 2] = 2
    actions = np.array([[[3, 4], [2, 0], [2, 0], [2, -1], [-1, -1]]])  # (1, T=5, 2)
    positions = np.zeros((1, 6, 2, 2), dtype=np.int64)  # both agents stay off the target
    shares = why.move_shares(actions, positions, grid)
    # A: Right then Left (undo), Left, Left (repeats); B: after Stay not counted, Up, Up.
    assert shares == {"undo": 0.25, "repeat": 0.75}
    positions[0, 2:, 0] = (2, 2)  # A on the target from its third move on: not counted
    assert why.move_shares(actions, positions, grid) == {"undo": 0.5, "repeat": 0.5}
