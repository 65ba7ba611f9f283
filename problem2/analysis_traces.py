"""Picking single episodes out of a batch of recorded test episodes, for the figures."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from analysis_failures import FAILURE_KINDS, classify_failures
from rollout import EpisodeResults


@dataclass
class EpisodeTrace:
    """One recorded episode: positions (L + 1, 2, 2) as (row, col), messages sent (L, 2)."""

    positions: np.ndarray
    messages: np.ndarray
    success: bool
    description: str = ""

    @property
    def length(self) -> int:
        return len(self.messages)


def episode_trace(results: EpisodeResults, index: int, description: str = "") -> EpisodeTrace:
    """Episode ``index`` of recorded ``results``, cut to its length."""
    if results.trajectories is None:
        raise ValueError("episode traces need recorded episodes (record=True)")
    length = int(results.lengths[index])
    return EpisodeTrace(
        positions=results.trajectories["positions"][index, : length + 1],
        messages=results.trajectories["messages"][index, :length],
        success=bool(results.successes[index]),
        description=description,
    )


def representative_success(results: EpisodeResults, label: str) -> EpisodeTrace | None:
    """The first successful episode whose length is the median successful length."""
    successful = np.flatnonzero(results.successes)
    if successful.size == 0:
        return None
    lengths = results.lengths[successful]
    index = successful[np.argmin(np.abs(lengths - np.median(lengths)))]
    return episode_trace(results, int(index), label)


def representative_failure(
    results: EpisodeResults, target: tuple[int, int], label: str
) -> EpisodeTrace | None:
    """The first failed episode of the most common failure kind."""
    kinds = classify_failures(results, target)
    failed = kinds[kinds >= 0]
    if failed.size == 0:
        return None
    common = int(np.bincount(failed, minlength=len(FAILURE_KINDS)).argmax())
    index = int(np.flatnonzero(kinds == common)[0])
    return episode_trace(results, index, f"{FAILURE_KINDS[common]}, {label}")


def representative_traces(
    runs: dict[str, EpisodeResults], target: tuple[int, int]
) -> list[EpisodeTrace | None]:
    """[successful, failed] episode, each from the greedy run if it has one, else from the
    ε-greedy run (``runs`` keyed ``greedy`` and ``eps``); None where neither has one."""
    order = [(name, "greedy" if name == "greedy" else "ε-greedy") for name in ("greedy", "eps")]
    success = failure = None
    for name, label in order:
        if name in runs:
            success = success or representative_success(runs[name], label)
            failure = failure or representative_failure(runs[name], target, label)
    return [success, failure]
