"""Replay buffers: ring storage, extras, seeded sampling, the sum-tree, PER weights, and the
refusal of malformed transitions."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from replay import TRANSITION_FIELDS, sample_batch
from replay_buffer import PrioritizedReplayBuffer, ReplayBuffer, SumTree
from rollout import NStepWindow


def batch_of(first: int, count: int, obs_dim: int = 11) -> dict[str, np.ndarray]:
    """``count`` transitions numbered from ``first``; every field encodes the number."""
    ids = np.arange(first, first + count)
    state = np.repeat(ids[:, None], obs_dim, axis=1).astype(np.float32)
    fields = {name: state + k for k, name in enumerate(["state_A", "state_B"])}
    fields |= {"next_state_A": state + 0.5, "next_state_B": state + 0.75}
    fields |= {"action_A": ids % 5, "action_B": (ids + 1) % 5, "done": ids % 2 == 0}
    fields |= {"comm_A": ids / 1000, "comm_B": ids / 2000, "reward": -ids.astype(float)}
    return fields


def test_ring_buffer_keeps_the_latest_transitions() -> None:
    buffer = ReplayBuffer(capacity=5, seed=0)
    buffer.push_batch(**batch_of(0, 3))
    buffer.push_batch(**batch_of(3, 4))
    assert len(buffer) == 5
    states = np.concatenate([buffer.sample(5)[0] for _ in range(40)])
    assert set(states[:, 0].tolist()) == {2.0, 3.0, 4.0, 5.0, 6.0}
    buffer.push_batch(**batch_of(100, 12))  # more than the capacity: keep the last five
    assert set(buffer.fields_at(np.arange(5))[0][:, 0].tolist()) == {107, 108, 109, 110, 111}


@pytest.mark.parametrize("buffer_class", [ReplayBuffer, PrioritizedReplayBuffer])
def test_a_pair_of_agent_fields_is_one_array_with_the_agent_axis_first(buffer_class: type) -> None:
    """get() reads, at the drawn slots, A's and B's fields as one (2, B, ...) block (what
    both agents' networks take in one pass), also after pushes across the end of the ring;
    new slots get the largest priority (PER)."""
    batch = batch_of(0, 7)
    buffer = buffer_class(5, seed=0)
    assert np.array_equal(buffer.push_batch(**{k: v[:4] for k, v in batch.items()}), range(4))
    assert np.array_equal(buffer.push_batch(**{k: v[4:] for k, v in batch.items()}), [4, 0, 1])
    indices = buffer.sample_indices(5)
    stored = buffer.get(indices)
    assert stored["state"].shape == (2, 5, 11) and stored["action"].shape == (2, 5)
    assert stored["action"].dtype == np.int64 and stored["state"].dtype == np.float32
    fields = dict(zip(TRANSITION_FIELDS, buffer.fields_at(indices), strict=True))
    for name in ("state", "next_state", "action", "comm"):
        assert np.array_equal(stored[name][0], fields[f"{name}_A"]), name
        assert np.array_equal(stored[name][1], fields[f"{name}_B"]), name
    assert np.array_equal(stored["reward"], fields["reward"])
    assert set(buffer.fields_at(np.arange(5))[0][:, 0].tolist()) == {2, 3, 4, 5, 6}
    if buffer_class is PrioritizedReplayBuffer:
        assert np.allclose(buffer._tree.values(np.arange(5)), 1.0)  # max priority 1 so far


def test_a_learner_batch_holds_the_sampled_transitions_as_tensors() -> None:
    """sample_batch: (2, B, D) observations, (2, B) actions, and for transitions pushed by
    hand the discount γ (1 − done), no previous observation, last_obs = obs."""
    buffer = ReplayBuffer(50, seed=3)
    buffer.push_batch(**batch_of(0, 30))
    batch = sample_batch(buffer, 16, gamma=0.9)
    ids = batch.obs[0, :, 0].long()
    assert torch.equal(batch.obs[1, :, 0], ids.float() + 1)
    assert torch.equal(batch.actions[0], ids % 5) and batch.actions.dtype == torch.int64
    assert torch.allclose(batch.discount, 0.9 * (1.0 - (ids % 2 == 0).float()))
    assert torch.equal(batch.last_obs, batch.obs) and not batch.has_prev.any()
    assert not batch.prev_obs.any()


def test_sampled_fields_stay_aligned_and_typed() -> None:
    buffer = ReplayBuffer(capacity=50, seed=1)
    buffer.push_batch(**batch_of(0, 30))
    sample = buffer.sample(30)
    fields = dict(zip(TRANSITION_FIELDS, sample, strict=True))
    ids = fields["state_A"][:, 0].astype(int)
    assert np.array_equal(fields["state_B"][:, 0], ids + 1)
    assert np.array_equal(fields["next_state_B"][:, 0], ids + 0.75)
    assert np.array_equal(fields["action_A"], ids % 5)
    assert np.allclose(fields["reward"], -ids)
    assert np.array_equal(fields["done"], (ids % 2 == 0).astype(np.float32))
    assert fields["action_A"].dtype == np.int64 and fields["done"].dtype == np.float32
    assert fields["state_A"].dtype == np.float32 and fields["reward"].dtype == np.float32


def test_single_push_and_batched_push_store_the_same() -> None:
    one_by_one, batched = ReplayBuffer(10), ReplayBuffer(10)
    batch = batch_of(0, 4)
    for i in range(4):
        one_by_one.push(*(batch[name][i] for name in TRANSITION_FIELDS))
    batched.push_batch(**batch)
    for name, values in one_by_one.get(np.arange(4)).items():
        assert np.array_equal(values, batched.get(np.arange(4))[name])


def test_sampling_is_seeded() -> None:
    def draw(seed: int) -> np.ndarray:
        buffer = ReplayBuffer(100, seed=seed)
        buffer.push_batch(**batch_of(0, 100))
        return buffer.sample(32)[0]  # with replacement, seeded

    assert np.array_equal(draw(3), draw(3))
    assert not np.array_equal(draw(3), draw(4))


def test_extras_are_stored_beside_the_required_fields() -> None:
    buffer = ReplayBuffer(20, seed=0)
    batch = batch_of(0, 8)
    partner = batch["state_B"] * 10
    buffer.push_batch(**batch, prev_partner_obs_A=partner, prev_partner_obs_B=partner + 1)
    assert buffer.field_names == (*TRANSITION_FIELDS, "prev_partner_obs_A", "prev_partner_obs_B")
    indices = buffer.sample_indices(8)
    stored = buffer.get(indices)
    assert np.array_equal(stored["prev_partner_obs"][0], stored["state"][1] * 10)
    assert np.array_equal(stored["prev_partner_obs"][1], stored["state"][1] * 10 + 1)
    assert indices.shape == (8,)
    assert len(buffer.sample(4)) == 10  # sample() keeps to the ten required arrays
    single = batch_of(50, 1)
    buffer.push(
        *(single[name][0] for name in TRANSITION_FIELDS),
        prev_partner_obs_A=np.zeros(11),
        prev_partner_obs_B=np.ones(11),
    )
    assert len(buffer) == 9


@pytest.mark.parametrize("buffer_class", [ReplayBuffer, PrioritizedReplayBuffer])
def test_buffer_input_errors(buffer_class) -> None:
    buffer = buffer_class(capacity=10, seed=0)
    with pytest.raises(ValueError, match="holds 0"):
        buffer.sample(1)
    buffer.push_batch(**batch_of(0, 3, obs_dim=10))
    with pytest.raises(ValueError, match="cannot sample 4"):
        buffer.sample(4)
    with pytest.raises(ValueError, match="batch_size"):
        buffer.sample(0)
    with pytest.raises(ValueError, match="per-transition shape"):
        buffer.push_batch(**batch_of(3, 2, obs_dim=11))
    with pytest.raises(ValueError, match="missing required fields"):
        buffer.push_batch(**{k: v for k, v in batch_of(3, 2).items() if k != "reward"})
    with pytest.raises(ValueError, match="leading"):
        buffer.push_batch(**(batch_of(3, 2, obs_dim=10) | {"reward": np.zeros(3)}))
    with pytest.raises(ValueError, match="differ from those of the first push"):
        buffer.push_batch(**batch_of(3, 2, obs_dim=10), extra=np.zeros(2))
    with pytest.raises(ValueError, match="capacity"):
        buffer_class(capacity=0)
    assert len(buffer) == 3


# --------------------------------------------------------------------------- sum-tree
def test_sum_tree_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    tree = SumTree(13)  # not a power of two
    priorities = np.zeros(13)
    for _ in range(50):
        leaves = rng.choice(13, size=rng.integers(1, 6), replace=False)
        priorities[leaves] = rng.random(len(leaves)) * 5 + 0.01
        tree.update(leaves, priorities[leaves])
        assert tree.total == pytest.approx(priorities.sum())
        prefix_sums = rng.random(20) * priorities.sum()
        expected = np.searchsorted(np.cumsum(priorities), prefix_sums, side="right")
        assert np.array_equal(tree.find(prefix_sums), expected)
    assert np.allclose(tree.values(np.arange(13)), priorities)


def test_sum_tree_of_one_leaf() -> None:
    tree = SumTree(1)
    tree.update(np.array([0]), 3.0)
    assert tree.total == 3.0 and tree.find(np.array([0.0, 2.9])).tolist() == [0, 0]


@pytest.mark.parametrize("alpha", [1.0, 0.5])
def test_sampling_frequencies_follow_priorities(alpha: float) -> None:
    """Chi-square goodness of fit over 10 slots (9 degrees of freedom), 16 000 draws: the
    statistic must stay below 27.88, its 99.9 % quantile under multinomial sampling.
    Stratified sampling only lowers the variance, so the test errs on the safe side."""
    buffer = PrioritizedReplayBuffer(capacity=10, alpha=alpha, seed=0)
    buffer.push_batch(**batch_of(0, 10))
    priorities = np.arange(1.0, 11.0)
    buffer.update_priorities(np.arange(10), priorities)
    counts = np.zeros(10)
    for _ in range(1600):
        _, _, indices = buffer.sample(10)
        counts += np.bincount(indices, minlength=10)
    expected = counts.sum() * priorities**alpha / (priorities**alpha).sum()
    chi_square = ((counts - expected) ** 2 / expected).sum()
    assert chi_square < 27.88


def test_priority_weights_beta_and_new_transitions() -> None:
    buffer = PrioritizedReplayBuffer(capacity=8, alpha=0.5, beta_start=0.4, beta_steps=4, seed=0)
    buffer.push_batch(**batch_of(0, 4))
    buffer.update_priorities(np.arange(4), [1.0, 4.0, 9.0, 16.0])
    probabilities = np.array([1.0, 2.0, 3.0, 4.0]) / 10.0
    betas = []
    for _ in range(6):
        beta = buffer.beta
        betas.append(beta)
        _, weights, indices = buffer.sample(4)
        raw = (4 * probabilities[indices]) ** -beta
        assert weights.dtype == np.float32
        assert np.allclose(weights, raw / raw.max())
    assert betas == pytest.approx([0.4, 0.55, 0.7, 0.85, 1.0, 1.0])
    slots = buffer.push_batch(**batch_of(4, 1))
    assert slots.tolist() == [4]
    assert buffer._tree.values(slots)[0] == pytest.approx(16.0**0.5)  # the largest so far


def test_only_stored_slots_are_sampled() -> None:
    buffer = PrioritizedReplayBuffer(capacity=100, seed=0)
    buffer.push_batch(**batch_of(0, 3))
    for _ in range(200):
        _, _, indices = buffer.sample(3)
        assert indices.max() < 3


@pytest.mark.parametrize(
    ("indices", "priorities", "problem"),
    [
        ([0, 1], [1.0], "2 indices but 1 priorities"),
        ([0, 5], [1.0, 1.0], "stored slots"),
        ([-1], [1.0], "stored slots"),
        ([0], [0.0], "positive and finite"),
        ([0], [-1.0], "positive and finite"),
        ([0], [np.nan], "positive and finite"),
        ([0], [np.inf], "positive and finite"),
    ],
)
def test_update_priorities_rejects_bad_input(indices, priorities, problem: str) -> None:
    buffer = PrioritizedReplayBuffer(capacity=10)
    buffer.push_batch(**batch_of(0, 3))
    with pytest.raises(ValueError, match=problem):
        buffer.update_priorities(indices, priorities)


def test_prioritized_constructor_rejects_bad_hyperparameters() -> None:
    with pytest.raises(ValueError, match="alpha"):
        PrioritizedReplayBuffer(alpha=-0.1)
    with pytest.raises(ValueError, match="beta_start"):
        PrioritizedReplayBuffer(beta_start=1.5)
    with pytest.raises(ValueError, match="beta_steps"):
        PrioritizedReplayBuffer(beta_steps=0)


# ------------------------------------------------------------------- malformed input
GOOD = dict(
    state_A=np.zeros(11),
    state_B=np.zeros(11),
    action_A=1,
    action_B=4,
    comm_A=0.5,
    comm_B=1.0,
    reward=-0.1,
    next_state_A=np.zeros(11),
    next_state_B=np.zeros(11),
    done=False,
)


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"state_B": np.zeros(10)}, "state_B must be one observation vector"),
        ({"next_state_A": np.zeros((2, 11))}, "next_state_A must be one observation vector"),
        ({"state_A": np.full(11, np.nan)}, "state_A must hold finite numbers"),
        ({"reward": [1.0, 2.0]}, "reward must be one number per transition"),
        ({"action_A": 5}, r"action_A must lie in 0\.\.4"),
        ({"action_B": -1}, r"action_B must lie in 0\.\.4"),
        ({"action_A": 2.5}, "action_A must be integer actions"),
        ({"action_A": True}, "action_A must be integer actions"),
        ({"comm_A": 1.5}, r"comm_A must be a message in \[0, 1\]"),
        ({"comm_B": -0.2}, r"comm_B must be a message in \[0, 1\]"),
        ({"comm_B": np.nan}, r"comm_B must be a message in \[0, 1\]"),
        ({"reward": np.inf}, "reward must be a finite number"),
        ({"reward": np.nan}, "reward must be a finite number"),
        ({"done": 0.5}, "done must be boolean"),
        ({"done": 2}, "done must be boolean"),
        ({"comm_A": torch.tensor(0.5, requires_grad=True)}, "comm_A is a tensor that requires"),
        ({"reward": "high"}, "reward must be a finite number"),
    ],
)
@pytest.mark.parametrize("buffer_class", [ReplayBuffer, PrioritizedReplayBuffer])
def test_malformed_transitions_are_refused_by_name(buffer_class, change, problem: str) -> None:
    buffer = buffer_class(capacity=10)
    with pytest.raises(ValueError, match=problem):
        buffer.push(**(GOOD | change))
    assert len(buffer) == 0
    buffer.push(**GOOD)
    with pytest.raises(ValueError, match=problem):
        buffer.push(**(GOOD | change))
    assert len(buffer) == 1


def test_plain_tensors_numpy_scalars_and_zero_one_done_are_accepted() -> None:
    buffer = ReplayBuffer(capacity=10)
    buffer.push(**GOOD | {"comm_A": torch.tensor(0.25), "action_A": np.int64(3), "done": 1.0})
    buffer.push(**GOOD | {"state_A": torch.zeros(11), "done": np.True_})
    assert len(buffer) == 2 and buffer.sample(2)[9].dtype == np.float32


@pytest.mark.parametrize("capacity", [None, "10", 2.5, 0, True])
def test_capacity_must_be_a_positive_integer_and_is_named(capacity) -> None:
    with pytest.raises(ValueError, match="capacity must be a positive integer"):
        ReplayBuffer(capacity=capacity)


def test_update_priorities_needs_integer_indices_and_keeps_a_repeat_s_largest() -> None:
    buffer = PrioritizedReplayBuffer(capacity=10)
    buffer.push_batch(**batch_of(0, 3))
    with pytest.raises(ValueError, match="indices must be integers"):
        buffer.update_priorities([0.5, 1.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="indices must be integers"):
        buffer.update_priorities([True], [1.0])
    buffer.update_priorities([1, 1, 2], [3.0, 5.0, 1.0])  # a slot drawn twice by sample()
    assert buffer._tree.values(np.array([1]))[0] == pytest.approx(5.0**0.6)
    buffer.update_priorities([1, 1], [2.0, 0.5])  # the largest of this update, not of all time
    assert buffer._tree.values(np.array([1]))[0] == pytest.approx(2.0**0.6)


@pytest.mark.parametrize("n_step", [1, 2, 3])
def test_n_step_window_gives_each_step_its_discounted_k_step_return(n_step: int) -> None:
    """Against a direct per-episode computation: 3 copies with episodes of random length,
    ending by termination or cut-off."""
    gamma, n_envs, n_steps = 0.9, 3, 30
    rng = np.random.default_rng(0)
    window = NStepWindow(n_step, gamma, n_envs)
    rewards = rng.normal(size=(n_steps, n_envs))
    finished = rng.random((n_steps, n_envs)) < 0.25
    terminated = finished & (rng.random((n_steps, n_envs)) < 0.5)
    finished[-1] = terminated[-1] = True  # every episode ends
    observations = rng.normal(size=(n_steps + 1, n_envs, 2, 1))
    emitted = []
    for t in range(n_steps):
        start = {"step": np.full(n_envs, t), "env": np.arange(n_envs)}
        complete = window.add(
            start, rewards[t], observations[t + 1], observations[t], terminated[t], finished[t]
        )
        names = set(complete)
        assert names == {
            "step",
            "env",
            "next_state_A",
            "next_state_B",
            "reward",
            "done",
            "discount",
            "last_state_A",
            "last_state_B",
        }
        assert all(complete[k].dtype == np.float32 for k in ("reward", "done", "discount"))
        count = len(complete["reward"])
        emitted += [{name: complete[name][i].squeeze() for name in names} for i in range(count)]
    expected = []
    for env in range(n_envs):
        for t in range(n_steps):
            end = next(u for u in range(t, n_steps) if finished[u, env])
            k = min(n_step, end - t + 1)
            last = t + k - 1
            terminal = bool(terminated[last, env]) and last == end
            expected.append(
                {
                    "step": t,
                    "env": env,
                    "k": k,
                    "terminal": terminal,
                    "last": last,
                    "reward": sum(gamma**i * rewards[t + i, env] for i in range(k)),
                }
            )
    assert len(emitted) == len(expected)
    by_start = {(int(e["step"]), int(e["env"])): e for e in emitted}
    for want in expected:
        got = by_start[(want["step"], want["env"])]
        assert got["reward"] == pytest.approx(want["reward"], rel=1e-5, abs=1e-5)
        assert bool(got["done"]) == want["terminal"]
        after = observations[want["last"] + 1, want["env"], :, 0]  # A's, then B's
        assert [got["next_state_A"], got["next_state_B"]] == pytest.approx(after.tolist())
        assert got["discount"] == pytest.approx(0.0 if want["terminal"] else gamma ** want["k"])
        before = observations[want["last"], want["env"], :, 0]  # the state itself if n = 1
        assert [got["last_state_A"], got["last_state_B"]] == pytest.approx(before.tolist())
