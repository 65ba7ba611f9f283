"""Summary statistics of Problem 2's evaluation: percentile bootstrap intervals, the
interquartile mean, and the per-mode summary over training seeds."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

BOOTSTRAP_RESAMPLES = 10_000
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0


def bootstrap_ci(
    values: Sequence[float] | np.ndarray,
    confidence: float = CONFIDENCE,
    n_resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[float, float]:
    """Percentile bootstrap interval (low, high) of the mean of ``values`` (n,).

    Resampling n values with replacement only changes how often each distinct value is
    drawn, so a resample is drawn as multinomial counts over the distinct values: exact,
    and fast for success indicators (two distinct values) or per-seed rates. A constant
    sample (or a single value) gives a zero-width interval. NaN values are refused.
    """
    values = np.asarray(values, dtype=np.float64).ravel()
    if values.size == 0:
        raise ValueError("bootstrap_ci needs at least one value")
    if not np.isfinite(values).all():
        raise ValueError(f"bootstrap_ci needs finite values, got {values}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    distinct, counts = np.unique(values, return_counts=True)
    if distinct.size == 1:
        return float(distinct[0]), float(distinct[0])
    rng = np.random.default_rng(seed)
    resampled = rng.multinomial(values.size, counts / values.size, size=n_resamples)
    means = resampled @ distinct / values.size  # (n_resamples,)
    tail = (1 - confidence) / 2
    low, high = np.quantile(means, [tail, 1 - tail])
    return float(low), float(high)


def interquartile_mean(values: Sequence[float] | np.ndarray) -> float:
    """Mean of the middle half: sort, drop ``floor(n / 4)`` values at each end, average
    the rest (as ``scipy.stats.trim_mean(values, 0.25)``; the plain mean for n < 4)."""
    ordered = np.sort(np.asarray(values, dtype=np.float64).ravel())
    if ordered.size == 0:
        raise ValueError("interquartile_mean needs at least one value")
    cut = ordered.size // 4
    return float(ordered[cut : ordered.size - cut].mean())


def seed_statistics(
    values: Sequence[float | None], seed: int = BOOTSTRAP_SEED
) -> dict[str, float | list | int | None]:
    """Mean, 95 % bootstrap CI over seeds, IQM and the per-seed values (n_seeds,).

    ``None`` entries (e.g. steps to success of a seed that never succeeded) are kept in
    ``per_seed`` but left out of the statistics; ``n`` counts the values used."""
    present = [float(v) for v in values if v is not None and not math.isnan(v)]
    if not present:
        return {"mean": None, "ci95": None, "iqm": None, "n": 0, "per_seed": list(values)}
    low, high = bootstrap_ci(present, seed=seed)
    return {
        "mean": float(np.mean(present)),
        "ci95": [low, high],
        "iqm": interquartile_mean(present),
        "n": len(present),
        "per_seed": [None if v is None else float(v) for v in values],
    }


def paired_difference(
    first: np.ndarray, second: np.ndarray, n_resamples: int = 2_000, seed: int = BOOTSTRAP_SEED
) -> dict[str, float | list]:
    """Mean of ``first − second`` over paired episodes (E,) with its bootstrap CI."""
    difference = np.asarray(first, dtype=np.float64) - np.asarray(second, dtype=np.float64)
    low, high = bootstrap_ci(difference, n_resamples=n_resamples, seed=seed)
    return {"mean": float(difference.mean()), "ci95": [low, high]}
