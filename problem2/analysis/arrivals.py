"""Who stands on the target when, from recorded trajectories: the arrival measures every
study uses (:func:`arrivals`, the homing of an agent whose partner waits on the target:
:func:`homing_counts`) and the decomposition of failures into navigation (an agent never
reached the target) and timing (both did, never together)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rollout import EpisodeResults

from analysis.failures import on_target


@dataclass(frozen=True)
class Arrivals:
    """Per-episode arrival facts, from :func:`on_target` (E episodes)."""

    on: np.ndarray  # (E, T + 1, 2) bool: on the target at position t, within the episode
    reached: np.ndarray  # (E, 2) bool: the agent stood on the target at some step
    first_arrival: np.ndarray  # (E, 2) int: first position index on the target (valid if reached)
    steps_one_on_target: np.ndarray  # (E,) int: steps after which exactly one agent is on it

    @property
    def both_arrived(self) -> np.ndarray:
        """(E,) both agents stood on the target at some step (not necessarily together)."""
        return self.reached.all(axis=1)

    @property
    def one_never_arrives(self) -> np.ndarray:
        """(E,) exactly one agent ever stood on the target: the other never came."""
        return self.reached.sum(axis=1) == 1


def arrivals(positions: np.ndarray, lengths: np.ndarray, target: tuple[int, int]) -> Arrivals:
    """:class:`Arrivals` of recorded episodes (positions (E, T + 1, 2, 2), lengths (E,))."""
    on = on_target(positions, lengths, target)
    exactly_one = on[:, 1:, 0] != on[:, 1:, 1]  # (E, T); False past the end (both off)
    return Arrivals(on, on.any(axis=1), on.argmax(axis=1), exactly_one.sum(axis=1))


HOMING_KINDS = ("closer", "farther", "neither")


def homing_counts(results: EpisodeResults, distances: np.ndarray) -> np.ndarray:
    """Counts (3,) of ``HOMING_KINDS``, summed over both agents: the moves an agent made while
    its partner stood on the target and it did not, by whether the move brought it closer
    to the target, farther, or neither. ``distances`` (H, W): each cell's distance to the
    target (0 on it), e.g. ``analysis.episodes.target_distances`` (shortest paths)."""
    positions = results.trajectories["positions"]  # (E, T + 1, 2, 2)
    distance = np.asarray(distances)[positions[..., 0], positions[..., 1]]  # (E, T + 1, 2)
    on = distance == 0
    horizon = positions.shape[1] - 1
    steps = (np.arange(horizon)[None, :] < results.lengths[:, None])[..., None]  # (E, T, 1)
    waiting = steps & on[:, :-1, ::-1] & ~on[:, :-1]  # partner on the target, agent not
    change = distance[:, 1:] - distance[:, :-1]
    return np.array([(waiting & op(change, 0)).sum() for op in (np.less, np.greater, np.equal)])


def homing_shares(counts: np.ndarray | list[float]) -> dict[str, float]:
    """Each kind's share of the counted moves (0 for every kind if none was counted)."""
    total = max(float(np.sum(counts)), 1.0)
    return {kind: float(c) / total for kind, c in zip(HOMING_KINDS, counts, strict=True)}


DECOMPOSITION = {
    "navigation": "a failed episode in which at least one agent never reached the target",
    "timing": "a failed episode in which both agents reached the target, never on the same step",
    "reached_and_left": "a failed episode in which an agent stepped off the target after "
    "reaching it (overlaps the two kinds above)",
    "stay_on_target_share": "share of the steps begun by an agent on the target on which it is "
    "still there after the step (all episodes)",
    "stay_share_more_staying": "the same share for each agent alone: the larger of the two "
    "(the agent that waits on the target more); both agents must have begun a step on it",
    "stay_share_less_staying": "the smaller of the two agents' own shares (the agent that "
    "waits less)",
}


def failure_decomposition(results: EpisodeResults, target: tuple[int, int]) -> dict:
    """Shares of the failed episodes by ``DECOMPOSITION`` (None if none failed) and the share
    of on-target steps on which the agent stays, pooled and per agent (the larger and the
    smaller of the two; None unless both agents began a step on the target). Needs recorded
    episodes."""
    if results.trajectories is None:
        raise ValueError("failure_decomposition needs recorded episodes (record=True)")
    positions = results.trajectories["positions"]  # (E, T + 1, 2, 2)
    horizon = positions.shape[1] - 1
    arrived = arrivals(positions, results.lengths, target)
    on, reached = arrived.on, arrived.reached  # (E, T + 1, 2), (E, 2)
    failed = ~results.successes
    taken = (np.arange(horizon)[None, :] < results.lengths[:, None])[..., None]  # (E, T, 1)
    began_on = on[:, :-1] & taken  # steps begun on the target
    stayed = began_on & on[:, 1:]  # ... and still on it after the step
    left = (began_on & ~on[:, 1:]).any(axis=(1, 2))
    count = int(failed.sum())
    began_by_agent = began_on.sum(axis=(0, 1))  # (2,)
    stays_by_agent = stayed.sum(axis=(0, 1)) / np.maximum(began_by_agent, 1)
    both_began = bool(began_by_agent.all())

    def share(kind: np.ndarray) -> float | None:
        return float((kind & failed).sum() / count) if count else None

    return {
        "failed_episodes": count,
        "navigation": share(~reached.all(axis=1)),
        "timing": share(reached.all(axis=1)),
        "reached_and_left": share(left),
        "stay_on_target_share": float(stayed.sum() / began_on.sum()) if began_on.any() else None,
        "stay_share_more_staying": float(stays_by_agent.max()) if both_began else None,
        "stay_share_less_staying": float(stays_by_agent.min()) if both_began else None,
        "steps_begun_on_target": int(began_on.sum()),
    }
