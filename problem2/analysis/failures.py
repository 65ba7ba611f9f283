"""How test episodes fail, from recorded trajectories: the kind of each failed episode (what
the agents do in its last steps) and the share of each kind. (Who reaches the target when,
and the decomposition of failures into navigation and timing: :mod:`analysis.arrivals`.)"""

from __future__ import annotations

import numpy as np
from rollout import EpisodeResults


def on_target(positions: np.ndarray, lengths: np.ndarray, target: tuple[int, int]) -> np.ndarray:
    """(E, T + 1, 2) bool: agent i stands on the target at position t of episode e, counting
    only the positions of the episode (t <= length; a recording holds the last position after
    the end). ``positions`` (E, T + 1, 2, 2) as recorded by ``rollout.run_episodes``."""
    within = np.arange(positions.shape[1])[None, :] <= np.asarray(lengths)[:, None]  # (E, T + 1)
    return np.all(positions == np.asarray(target), axis=-1) & within[..., None]


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
    ever_on_target = on_target(positions, results.lengths, tuple(target)).any(axis=1)  # (E, 2)
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
