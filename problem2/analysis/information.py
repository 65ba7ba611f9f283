"""The emergent-communication measures of Lowe et al. (2019), "On the pitfalls of measuring
emergent communication", on recorded greedy test episodes. The scalar message is binned
(``K = 2``: below / from 0.5; ``K = 10``: tenths of [0, 1]); information is in bits and
estimated by plug-in counts (biased upwards for small samples: the independent mode, whose
partner never reads the message, is the reference).

* ``speaker_consistency``: I(m_t^A; a_t^A), the sender's message and its own action at the
  same step (and the same for B).
* ``instantaneous_coordination``: I(m_t^A; a_{t+1}^B), A's message and the action B takes
  after receiving it (and the same from B to A).
* ``cic`` (causal influence of communication): for receiver observations x from the
  episodes, each bin centre is fed as the message; p(a | do(m)) is the receiver's ε-greedy
  policy, p(a) = Σ_m p(m) p(a | do(m)) with p(m) the sender's bin frequencies, and
  CIC(x) = Σ_m p(m) KL(p(a | do(m)) ‖ p(a)), averaged over the observations.
* ``positive_signalling``: I(m; sender on the target) and I(m; sender's distance to the target,
  in steps, capped at ``DISTANCE_CAP``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from rollout import EpisodeResults
from vector_env import NUM_ACTIONS, TARGET

from analysis.episodes import target_distances

BIN_COUNTS = (2, 10)
DISTANCE_CAP = 10  # distances of 10 steps and more share one bin
AGENTS = ("A", "B")
MEASURES = {
    "speaker_consistency": "I(m_t; a_t) of the sender, bits",
    "instantaneous_coordination": "I(m_t of the sender; a_{t+1} of the receiver), bits",
    "cic": "causal influence of communication on the receiver's ε-greedy policy, bits",
    "positive_signalling_on_target": "I(m_t; sender on the target), bits",
    "positive_signalling_distance": f"I(m_t; sender's BFS distance to the target, capped at "
    f"{DISTANCE_CAP}), bits",
}
QFunction = Callable[[np.ndarray], np.ndarray]  # observations (S, obs_dim) -> Q (S, 5)


def message_bins(messages: np.ndarray, bins: int) -> np.ndarray:
    """Bin index (same shape, int64) of messages in [0, 1]: ``bins`` equal-width bins."""
    return np.minimum((np.asarray(messages) * bins).astype(np.int64), bins - 1)


def bin_centres(bins: int) -> np.ndarray:
    return (np.arange(bins) + 0.5) / bins


def mutual_information(x: np.ndarray, y: np.ndarray) -> float:
    """Plug-in mutual information (bits) of two paired samples of small non-negative ints."""
    x, y = np.asarray(x, dtype=np.int64).ravel(), np.asarray(y, dtype=np.int64).ravel()
    if x.size == 0:
        return 0.0
    joint = np.zeros((x.max() + 1, y.max() + 1))
    np.add.at(joint, (x, y), 1.0)
    joint /= x.size
    outer = joint.sum(axis=1, keepdims=True) * joint.sum(axis=0, keepdims=True)
    present = joint > 0
    return float(max(0.0, (joint[present] * np.log2(joint[present] / outer[present])).sum()))


def epsilon_greedy(q_values: np.ndarray, epsilon: float) -> np.ndarray:
    """Action probabilities (S, 5) of the ε-greedy policy on Q-values (S, 5)."""
    probabilities = np.full(q_values.shape, epsilon / NUM_ACTIONS)
    probabilities[np.arange(len(q_values)), q_values.argmax(axis=1)] += 1 - epsilon
    return probabilities


def causal_influence(
    q_function: QFunction,
    observations: np.ndarray,
    message_index: int,
    message_probabilities: np.ndarray,
    epsilon: float,
) -> float:
    """Mean CIC (bits) over receiver ``observations`` (S, obs_dim): the receiver's ε-greedy
    policy with each bin centre fed as the message, weighted by ``message_probabilities``
    (K,)."""
    bins = len(message_probabilities)
    policies = []
    for centre in bin_centres(bins):
        changed = observations.copy()
        changed[:, message_index] = centre
        policies.append(epsilon_greedy(q_function(changed), epsilon))
    conditional = np.stack(policies, axis=1)  # (S, K, 5)
    p_m = message_probabilities[None, :, None]
    marginal = (p_m * conditional).sum(axis=1, keepdims=True)  # (S, 1, 5)
    present = conditional > 0  # 0 · log 0 = 0 (ε = 0 gives zero probabilities)
    ratio = np.where(present, conditional, 1.0) / np.where(present, marginal, 1.0)
    divergence = np.maximum((conditional * np.log2(ratio)).sum(axis=2), 0.0)  # (S, K), ≥ 0
    return float((message_probabilities[None, :] * divergence).sum(axis=1).mean())


def communication_measures(
    recorded: EpisodeResults,
    grid: np.ndarray,
    q_functions: tuple[QFunction, QFunction],
    epsilon: float,
    max_states: int = 2000,
    seed: int = 0,
) -> dict[str, dict]:
    """Every measure of ``MEASURES`` for K in ``BIN_COUNTS``, per direction (sender A and
    B): ``{"K2": {"speaker_consistency": {"A": x, "B": y}, ...}, "K10": ...}``.
    ``q_functions`` map raw observations of agent A / B to Q-values; CIC uses at most
    ``max_states`` receiver observations drawn from the real steps."""
    trajectories = recorded.trajectories
    if trajectories is None:
        raise ValueError("communication measures need recorded episodes (record=True)")
    messages, actions = trajectories["messages"], trajectories["actions"]  # (E, T, 2)
    observations = trajectories["observations"]  # (E, T + 1, 2, D)
    horizon = actions.shape[1]
    valid = actions[..., 0] >= 0  # (E, T)
    follows = valid[:, :-1] & valid[:, 1:]  # a step with a next step
    positions = trajectories["positions"][:, :horizon]
    target = np.argwhere(grid == TARGET)[0]
    on_target = np.all(positions == target, axis=-1)  # (E, T, 2)
    distance = np.minimum(
        target_distances(grid)[positions[..., 0], positions[..., 1]], DISTANCE_CAP
    )
    message_index = observations.shape[-1] - 2
    rng = np.random.default_rng(seed)
    result: dict[str, dict] = {}
    for bins in BIN_COUNTS:
        binned = message_bins(np.nan_to_num(messages), bins)
        entry: dict[str, dict] = {name: {} for name in MEASURES}
        for sender, name in enumerate(AGENTS):
            receiver = 1 - sender
            sent = binned[..., sender]
            entry["speaker_consistency"][name] = mutual_information(
                sent[valid], actions[..., sender][valid]
            )
            entry["instantaneous_coordination"][name] = mutual_information(
                sent[:, :-1][follows], actions[:, 1:, receiver][follows]
            )
            entry["positive_signalling_on_target"][name] = mutual_information(
                sent[valid], on_target[..., sender][valid]
            )
            entry["positive_signalling_distance"][name] = mutual_information(
                sent[valid], distance[..., sender][valid]
            )
            p_m = np.bincount(sent[valid], minlength=bins) / max(1, valid.sum())
            states = observations[:, :horizon, receiver][valid]
            if len(states) > max_states:
                states = states[rng.choice(len(states), max_states, replace=False)]
            entry["cic"][name] = causal_influence(
                q_functions[receiver], states, message_index, p_m, epsilon
            )
        result[f"K{bins}"] = entry
    return result
