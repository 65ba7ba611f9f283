"""Who stands on the target when, and how test episodes fail, from recorded trajectories:
the arrival measures every study uses (:func:`on_target`, :func:`arrivals`, the homing of an
agent whose partner waits on the target: :func:`homing_counts`), the kind of each
failed episode (what the agents do at the end) and the decomposition of failures into
navigation (an agent never reached the target) and timing (both did, never together)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rollout import EpisodeResults


def on_target(positions: np.ndarray, lengths: np.ndarray, target: tuple[int, int]) -> np.ndarray:
    """(E, T + 1, 2) bool: agent i stands on the target at position t of episode e, counting
    only the positions of the episode (t <= length; a recording holds the last position after
    the end). ``positions`` (E, T + 1, 2, 2) as recorded by ``rollout.run_episodes``."""
    within = np.arange(positions.shape[1])[None, :] <= np.asarray(lengths)[:, None]  # (E, T + 1)
    return np.all(positions == np.asarray(target), axis=-1) & within[..., None]


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
    target (0 on it), e.g. ``analysis.baselines.target_distances`` (shortest paths)."""
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


FAILURE_KINDS = ("swapping", "parked", "looping", "other")
FAILURE_WINDOW = 10  # the last steps of a failed episode that its classification looks at
LOOP_CELLS = 4  # at most this many distinct cells per agent in the window: looping
PARKED_SHARE = 0.5  # on the target at least this share of the window: parked
SWAP_RADIUS = 2  # Manhattan distance from the target within which a swap counts
FAILURE_DEFINITIONS = {
    "window": f"the last {FAILURE_WINDOW} steps of a failed (timed-out) episode",
    "swapping": f"at least 2 steps of the window in which the agents exchange cells, both "
    f"cells within Manhattan distance {SWAP_RADIUS} of the target",
    "parked": f"one agent on the target at the end and at >= {PARKED_SHARE:.0%} of the "
    "window's positions, the other never on it in the episode",
    "looping": f"each agent visits at most {LOOP_CELLS} distinct cells in the window "
    "(moving among a few cells or standing still)",
    "other": "none of the above; kinds are checked in the order listed",
}


def classify_failures(results: EpisodeResults, target: tuple[int, int]) -> np.ndarray:
    """Failure kind of each episode (E,) as an index into ``FAILURE_KINDS``; −1 on success.

    A failed episode ran the full ``T`` steps; its window, the last ``FAILURE_WINDOW`` steps
    (W, so W + 1 positions), is examined and the first matching kind, in this order, is its
    kind (the thresholds leave room for the odd random move of an ε-greedy policy):

    * ``swapping``: at least two of the W steps are swaps — each agent moves into the cell
      the other just left — between cells within Manhattan distance ``SWAP_RADIUS`` of the
      target (the two agents keep trading places next to it);
    * ``parked``: one agent is on the target at the last position and at least a share
      ``PARKED_SHARE`` of the window's positions, and the other never stood on it in the
      whole episode;
    * ``looping``: each agent visits at most ``LOOP_CELLS`` distinct cells in the window
      (both keep moving among a few cells, or stand still);
    * ``other``: none of these (e.g. still wandering when time ran out).

    Needs ``results`` recorded (``record=True``).
    """
    if results.trajectories is None:
        raise ValueError("classify_failures needs recorded episodes (record=True)")
    positions = results.trajectories["positions"]  # (E, T + 1, 2, 2)
    window = positions[:, -(FAILURE_WINDOW + 1) :]  # (E, W + 1, 2, 2)
    target = np.asarray(target)
    before, after = window[:, :-1], window[:, 1:]
    swaps = (
        np.all(after[:, :, 0] == before[:, :, 1], axis=-1)
        & np.all(after[:, :, 1] == before[:, :, 0], axis=-1)
        & np.any(before[:, :, 0] != before[:, :, 1], axis=-1)
        & np.all(np.abs(before - target).sum(axis=-1) <= SWAP_RADIUS, axis=-1)
    )  # (E, W)
    on_window = np.all(window == target, axis=-1)  # (E, W + 1, 2)
    ever_on_target = arrivals(positions, results.lengths, tuple(target)).reached  # (E, 2)
    stays = on_window[:, -1] & (on_window.mean(axis=1) >= PARKED_SHARE)  # (E, 2)
    parked = (stays & ~ever_on_target[:, ::-1]).any(axis=1)
    cells = window[..., 0] * (positions[..., 1].max() + 1) + window[..., 1]  # (E, W + 1, 2)
    ordered = np.sort(cells, axis=1)
    distinct = 1 + (np.diff(ordered, axis=1) != 0).sum(axis=1)  # (E, 2)
    looping = np.all(distinct <= LOOP_CELLS, axis=1)
    kinds = np.select(
        [swaps.sum(axis=1) >= 2, parked, looping], [0, 1, 2], default=FAILURE_KINDS.index("other")
    )
    return np.where(results.successes, -1, kinds)


def failure_shares(
    results: EpisodeResults, target: tuple[int, int]
) -> dict[str, float | int | None]:
    """Number of failed episodes and the share of each kind among them (None if none
    failed)."""
    kinds = classify_failures(results, target)
    failed = kinds[kinds >= 0]
    shares: dict[str, float | int | None] = {"failed_episodes": int(failed.size)}
    for index, kind in enumerate(FAILURE_KINDS):
        shares[kind] = float(np.mean(failed == index)) if failed.size else None
    return shares


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
