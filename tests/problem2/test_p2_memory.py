"""The memory agents (studies/memory): the exported file keeps the memory contract and
computes what the training network computes, the policy resets memory at episode starts,
episodes are stored whole, and the sequence TD target is the n-step Double-DQN target."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from analysis.episodes import recorded_episodes
from analysis.map_sets import training_maps
from multi_agent_env import MultiAgentEnv
from rollout import run_episodes
from settings import validated
from studies.memory.agents import (
    MEMORY_MODES,
    RecurrentQNetwork,
    export_recurrent,
    memory_policy,
    mode_mask,
)
from studies.memory.held_out_tests import memory_cic, memory_states
from studies.memory.learner import CURRICULUM_END, CurriculumEnv, Levers, RecurrentTrainer
from studies.pool_training import PoolConfig, PooledVectorEnv
from vector_env import MESSAGE_INDEX, TARGET, VectorMultiAgentEnv

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.\\w+` is deprecated:DeprecationWarning")


def test_masks_make_the_two_by_two_of_the_channels() -> None:
    masked = {mode: tuple(np.flatnonzero(mode_mask(mode) == 0)) for mode in MEMORY_MODES}
    assert masked == {"independent": (9, 10), "comm": (10,), "distance": (9,), "full": ()}
    with pytest.raises(ValueError, match="unknown mode 'both'"):
        mode_mask("both")


def test_exported_agent_keeps_the_contract_and_equals_the_training_network(tmp_path: Path) -> None:
    torch.manual_seed(0)
    network = RecurrentQNetwork("distance", hidden_dim=16)
    path = export_recurrent(network, tmp_path / "distance_seed0_agent_A.pt")
    loaded = torch.jit.load(str(path))
    obs, actions = torch.rand(7, 3, 11), torch.randint(-1, 5, (7, 3))
    q_seq, logits_seq, _ = network.unroll(obs, actions)
    h = loaded.initial_state(3)
    assert h.shape == (3, 16) and not h.any()
    for t in range(7):
        q, message, h = loaded(obs[t], actions[t], h)
        assert q.shape == (3, 5) and message.shape == (3, 1)
        torch.testing.assert_close(q, q_seq[t], atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(message[:, 0], torch.sigmoid(logits_seq[t]), atol=1e-6, rtol=0)
    # The mask is inside: the message (element 9) cannot change a distance agent's output.
    changed = obs[0].clone()
    changed[:, 9] = 1.0 - changed[:, 9]
    start = loaded.initial_state(3)
    torch.testing.assert_close(
        loaded(changed, actions[0], start)[0], loaded(obs[0], actions[0], start)[0]
    )
    # The same weights give the same bytes.
    again = export_recurrent(network, tmp_path / "again.pt")
    assert again.read_bytes() == path.read_bytes()


class Counter(torch.nn.Module):
    """A memory agent whose state counts its steps and whose message shows the action it
    was told it made before (0 at an episode start)."""

    def initial_state(self, batch_size: int) -> torch.Tensor:
        return torch.zeros(batch_size, 1)

    def forward(self, obs, prev_action, h):  # type: ignore[no-untyped-def]
        q = torch.zeros(len(obs), 5)
        q[:, 3] = h[:, 0] % 2  # Right on odd counts, otherwise Up
        return q, (prev_action.float() + 1).unsqueeze(-1) / 10, h + 1


def test_memory_policy_resets_the_state_at_every_episode_start() -> None:
    env = VectorMultiAgentEnv(4, seed=641, max_steps=5)
    seen: list[np.ndarray] = []
    policy = memory_policy((Counter(), Counter()), env)

    def recording(obs, positions):  # type: ignore[no-untyped-def]
        actions, messages = policy(obs, positions)
        seen.append(messages.copy())
        return actions, messages

    results = run_episodes(env, recording, 8, seed=3)
    assert len(results.lengths) == 8
    # Each round's first call sees prev_action -1 (message 0.0), whatever the last round did.
    firsts = [m for i, m in enumerate(seen) if i % 5 == 0]
    assert len(firsts) == 2 and all(np.allclose(m, 0.0) for m in firsts)
    assert not np.allclose(seen[1], 0.0)  # the action taken is fed back


def small_trainer(tmp_path: Path, mode: str, **settings: object) -> RecurrentTrainer:
    cfg = validated(
        PoolConfig(
            **{
                "total_steps": 2_000,
                "num_envs": 8,
                "batch_size": 64,
                "learning_starts": 400,
                "eval_interval": 1_000,
                "eval_episodes": 8,
                "hidden_dim": 16,
                "n_step": 3,
                "gamma": 0.9,
                "map_pool": 20,
                "validation_maps": 4,
                "share_weights": True,
                "potential_credit": "team",
                "output_dir": str(tmp_path),
                "seed": 5,
            }
            | settings,
        ),
    )
    return RecurrentTrainer(MultiAgentEnv(max_steps=12), cfg, mode)


def test_memory_agents_refuse_the_per_agent_arrival_term(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="potential_credit must be team for memory agents"):
        small_trainer(tmp_path, "full", potential_credit="agent")


def test_episodes_are_stored_whole_and_training_exports_the_pair(tmp_path: Path) -> None:
    trainer = small_trainer(tmp_path, "full")
    trainer.train()
    buffer = trainer.replay_buffer
    assert len(buffer) > 0 and trainer.updates > 0
    for row in range(len(buffer)):
        length = buffer.lengths[row]
        assert 1 <= length <= 12 and (length == 12 or buffer.terminated[row])
        assert (buffer.actions[row, :length] >= 0).all() and (
            buffer.actions[row, length:] == -1
        ).all()
        assert (buffer.rewards[row, length:] == 0).all()
    for agent in "AB":
        loaded = torch.jit.load(str(tmp_path / "agent_models" / f"full_seed5_agent_{agent}.pt"))
        assert loaded.initial_state(2).shape == (2, 16)
    assert (tmp_path / "agent_models" / "last_weights" / "full_seed5_agent_A.pt").exists()


def naive_targets(trainer: RecurrentTrainer, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """The n-step Double-DQN targets (T, 2E) step by step, from the same unrolls."""
    cfg = trainer.cfg
    episodes = len(batch["lengths"])
    obs = batch["obs"].permute(1, 2, 0, 3).reshape(-1, 2 * episodes, 11)
    actions = batch["actions"].permute(1, 2, 0).reshape(obs.shape[0] - 1, -1)
    previous = torch.cat([torch.full_like(actions[:1], -1), actions], 0)
    with torch.no_grad():
        q_online = trainer.online.unroll(obs, previous)[0]
        q_target = trainer.target.unroll(obs, previous)[0]
    targets = torch.zeros(actions.shape)
    for column in range(2 * episodes):
        e = column % episodes
        length, terminal = int(batch["lengths"][e]), bool(batch["terminated"][e])
        for t in range(length):
            k = min(cfg.n_step, length - t)
            value = sum(cfg.gamma**j * float(batch["rewards"][e, t + j]) for j in range(k))
            if not (terminal and t + k == length):
                best = int(q_online[t + k, column].argmax())
                value += cfg.gamma**k * float(q_target[t + k, column, best])
            targets[t, column] = value
    return targets


@pytest.mark.parametrize("mode", ["independent", "distance"])
def test_sequence_target_is_the_n_step_double_dqn_target(tmp_path: Path, mode: str) -> None:
    trainer = small_trainer(tmp_path, mode)
    trainer.train()
    torch.manual_seed(1)
    for p in trainer.target.parameters():  # target and online differ
        p.add_(0.1 * torch.randn_like(p))
    batch = trainer.replay_buffer.sample(6)
    _, errors, q_taken = trainer.td_loss(batch)
    expected = naive_targets(trainer, batch)
    lengths = batch["lengths"].repeat(2)
    valid = torch.arange(expected.shape[0])[:, None] < lengths[None, :]
    torch.testing.assert_close(q_taken - errors, expected[valid], atol=1e-5, rtol=1e-5)


def test_dial_trains_the_partners_message_head(tmp_path: Path) -> None:
    trainer = small_trainer(tmp_path, "comm", total_steps=800)
    trainer.train()
    loss, _, _ = trainer.td_loss(trainer.replay_buffer.sample(4))
    trainer.optimizer.zero_grad()
    loss.backward()
    assert trainer.online.message_head.weight.grad.abs().sum() > 0
    plain = small_trainer(tmp_path / "plain", "distance", total_steps=800)
    plain.train()
    loss, _, _ = plain.td_loss(plain.replay_buffer.sample(4))
    plain.optimizer.zero_grad()
    loss.backward()
    assert (
        plain.online.message_head.weight.grad is None
        or not plain.online.message_head.weight.grad.any()
    )


def test_same_seed_same_models(tmp_path: Path) -> None:
    first = small_trainer(tmp_path / "a", "full", total_steps=800)
    first.train()
    second = small_trainer(tmp_path / "b", "full", total_steps=800)
    second.train()
    name = "agent_models/full_seed5_agent_A.pt"
    assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_levers_are_checked() -> None:
    with pytest.raises(ValueError, match="listening must be a finite number >= 0"):
        Levers(listening=-1.0)
    with pytest.raises(ValueError, match=r"curriculum must be a share in \[0, 1\]"):
        Levers(curriculum=1.5)


def test_curriculum_starts_that_share_of_episodes_with_one_agent_on_the_target() -> None:
    env = CurriculumEnv(2000, map_pool=training_maps(30), seed=4, track_coverage=True)
    env.reset()
    env.start_on_target = 0.5
    rng = np.random.default_rng(0)
    for _ in range(env.max_steps):  # nearly every episode is cut off now and restarts
        obs, *_ = env.step(rng.integers(0, 5, (2000, 2)), np.zeros((2000, 2)))
    starts = env.steps == 0
    assert starts.mean() > 0.9
    on = (env.positions == env.target_positions[:, None]).all(axis=-1)[starts]  # (S, 2)
    assert not on.all(axis=1).any()
    assert 0.45 < on.any(axis=1).mean() < 0.58  # 0.5 drawn, plus starts that fell there
    assert abs(on[:, 0].mean() - on[:, 1].mean()) < 0.04  # A or B at random
    np.testing.assert_array_equal(obs[starts][..., 4] == TARGET, on)  # what each agent sees
    np.testing.assert_array_equal(env._visited[starts], on)  # no arrival reward for that
    env.start_on_target = 0.0  # the plain environment again: no draw, same episodes
    plain = PooledVectorEnv(50, map_pool=training_maps(30), seed=9)
    same = CurriculumEnv(50, map_pool=training_maps(30), seed=9)
    np.testing.assert_array_equal(plain.reset(), same.reset())


def test_curriculum_share_falls_to_zero_at_its_end(tmp_path: Path) -> None:
    plain = small_trainer(tmp_path, "full", total_steps=800)
    assert type(plain.rollout.env) is PooledVectorEnv  # without the lever
    levers = Levers(curriculum=0.6)
    taught = RecurrentTrainer(MultiAgentEnv(max_steps=12), plain.cfg, "full", levers)
    assert isinstance(taught.rollout.env, CurriculumEnv)
    shares = []
    while not taught.budget_spent():
        progress = taught.progress()  # the share is set from the progress before the step
        taught.collect(taught.rollout)
        shares.append((progress, taught.rollout.env.start_on_target))
    assert shares[0] == (0.0, 0.6)
    for progress, share in shares:
        assert share == pytest.approx(0.6 * max(0.0, 1 - progress / CURRICULUM_END))
    assert shares[-1][1] == 0.0
    assert [s for _, s in shares] == sorted((s for _, s in shares), reverse=True)


def test_distance_shaping_pays_c_times_d_minus_gamma_d_next(tmp_path: Path) -> None:
    plain = small_trainer(tmp_path / "plain", "full")
    shaped = small_trainer(tmp_path / "shaped", "full")
    shaped.levers = Levers(distance_potential=2.0)
    obs, final = np.zeros((2, 2, 11), np.float32), np.zeros((2, 2, 11), np.float32)
    obs[:, :, 10], final[:, :, 10] = [[0.5, 0.5], [0.2, 0.2]], [[0.3, 0.3], [0.0, 0.0]]
    info = {"on_target": np.zeros((2, 2), bool), "final_obs": final}
    rewards = np.array([-0.1, 10.0])
    difference = shaped.learning_rewards(rewards, info, obs) - plain.learning_rewards(
        rewards, info, obs
    )
    np.testing.assert_allclose(
        difference, 2.0 * (np.array([0.5, 0.2]) - 0.9 * np.array([0.3, 0.0]))
    )


def test_listening_and_signalling_losses_add_to_the_td_loss(tmp_path: Path) -> None:
    trainer = small_trainer(tmp_path, "full", total_steps=800)
    trainer.train()
    batch = trainer.replay_buffer.sample(4)

    def loss_with(levers: Levers) -> float:
        trainer.levers = levers
        trainer.noise_rng.manual_seed(0)
        return float(trainer.td_loss(batch)[0].detach())

    base = loss_with(Levers())
    assert loss_with(Levers(listening=0.5)) < base  # minus a non-negative policy change
    assert loss_with(Levers(signalling=0.5)) != base
    assert loss_with(Levers()) == base


def episodes_of(agents: tuple, epsilon: float) -> object:
    env = VectorMultiAgentEnv(30, seed=641, max_steps=20)
    return recorded_episodes(env, memory_policy(agents, env, epsilon, seed=2), 30, seed=4)


def test_memory_states_replay_what_the_agents_acted_on() -> None:
    torch.manual_seed(0)
    agents = (RecurrentQNetwork("full", 16), RecurrentQNetwork("full", 16))
    recorded = episodes_of(agents, 0.0)
    observations, actions = recorded.trajectories["observations"], recorded.trajectories["actions"]
    valid = actions[..., 0] >= 0
    for i, agent in enumerate(agents):
        previous, hidden = memory_states(agent, observations[:, :, i], actions[..., i])
        obs = torch.from_numpy(np.ascontiguousarray(observations[:, :-1, i][valid]))
        with torch.inference_mode():
            q, _, _ = agent(obs, torch.from_numpy(previous[valid]), torch.from_numpy(hidden[valid]))
        np.testing.assert_array_equal(q.numpy().argmax(axis=1), actions[..., i][valid])


class MessageFollower(torch.nn.Module):
    """A memory agent that moves up if the message it hears is at least 0.5, else down, and
    sends 0, 1, 0, 1, ... (its hidden state counts the steps); ``hears`` False: deaf."""

    def __init__(self, hears: bool) -> None:
        super().__init__()
        self.hears = hears

    def initial_state(self, batch_size: int) -> torch.Tensor:
        return torch.zeros(batch_size, 1)

    def forward(self, obs: torch.Tensor, prev_action: torch.Tensor, h: torch.Tensor) -> tuple:
        heard = obs[:, MESSAGE_INDEX] if self.hears else torch.zeros(len(obs))
        q = torch.zeros(len(obs), 5)
        q[:, 0], q[:, 1] = heard - 0.5, 0.5 - heard - 1e-3  # up where heard >= 0.5
        return q, (h % 2).clone(), h + 1


def test_memory_cic_is_zero_for_a_deaf_receiver_and_near_0_89_bits_for_a_follower() -> None:
    follower = (MessageFollower(hears=True), MessageFollower(hears=True))
    deaf = (MessageFollower(hears=False), MessageFollower(hears=False))
    heard = memory_cic(follower, episodes_of(follower, 0.0), 0.05)
    unheard = memory_cic(deaf, episodes_of(deaf, 0.0), 0.05)
    assert unheard == pytest.approx({"K2": 0.0, "K10": 0.0}, abs=1e-12)
    # Messages 0 and 1 about equally often; at eps 0.05 the follower's two policies put 0.96
    # on one move each: CIC = 0.96 log2(0.96 / 0.485) + 0.01 log2(0.01 / 0.485) = 0.890 bits.
    assert heard == pytest.approx({"K2": 0.890, "K10": 0.890}, abs=0.01)


def test_summarise_only_rewrites_what_the_run_wrote(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Re-summarising from the runs memory.json records gives the bytes the run wrote."""
    from studies.memory import study

    # A tiny run that still makes an update (one below learning_starts is refused), on a
    # small map pool with short episodes: the held-out tests (40 maps) take most of the time,
    # and re-summarising gives the run's bytes whatever the episodes' length.
    small = {"learning_starts": 1152, "max_steps": 10, "map_pool": 20, "validation_maps": 4}
    for key, value in small.items():
        monkeypatch.setitem(study.RECIPE, key, value)
    flags = ["--total_steps", "1200", "--num_seeds", "1", "--mode", "comm", "--workers", "1"]
    flags += ["--episodes_per_map", "2", "--output_dir", str(tmp_path)]
    study.main(flags)
    written = (tmp_path / "memory.json").read_bytes()
    (tmp_path / "memory.json").write_text(
        json.dumps(json.loads(written) | {"held_out": {}}), encoding="utf-8"
    )  # a summary that no longer matches its runs
    study.main([*flags, "--summarise_only"])
    assert (tmp_path / "memory.json").read_bytes() == written
