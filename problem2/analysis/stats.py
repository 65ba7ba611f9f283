"""Summary statistics of Problem 2's evaluation: percentile bootstrap intervals, the
interquartile mean, and the per-mode summary over training seeds."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

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


def seed_paired_differences(
    success: dict[tuple[str, int], dict[str, float]],
    pairs: Sequence[tuple[str, str]],
    conditions: Sequence[str],
) -> dict[str, dict]:
    """For each (first, second) pair of modes, keyed ``"first-second"``: per condition the
    :func:`seed_statistics` of first's success minus second's on each training seed both
    have (``success`` keyed (mode, seed)), and those ``seeds``. Pairs without a common seed
    are left out."""
    differences = {}
    for first, second in pairs:
        seeds = sorted(s for m, s in success if m == first and (second, s) in success)
        if seeds:
            differences[f"{first}-{second}"] = {
                c: seed_statistics([success[first, s][c] - success[second, s][c] for s in seeds])
                for c in conditions
            } | {"seeds": seeds}
    return differences


def paired_difference(
    first: np.ndarray, second: np.ndarray, n_resamples: int = 2_000, seed: int = BOOTSTRAP_SEED
) -> dict[str, float | list]:
    """Mean of ``first − second`` over paired episodes (E,) with its bootstrap CI."""
    difference = np.asarray(first, dtype=np.float64) - np.asarray(second, dtype=np.float64)
    low, high = bootstrap_ci(difference, n_resamples=n_resamples, seed=seed)
    return {"mean": float(difference.mean()), "ci95": [low, high]}


def _resampled_episode_weights(rng: np.random.Generator, size: int, episodes: int) -> np.ndarray:
    """(size, E) float32 counts: how often each episode is drawn in each of ``size``
    resamples of E episodes with replacement."""
    drawn = rng.integers(0, episodes, (size, episodes)) + episodes * np.arange(size)[:, None]
    counts = np.bincount(drawn.ravel(), minlength=size * episodes)
    return counts.reshape(size, episodes).astype(np.float32)


def mode_contrasts(
    successes: dict[str, np.ndarray],
    contrasts: dict[str, dict[str, float]],
    n_resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
    chunk: int = 1_000,
) -> dict[str, dict[str, Any]]:
    """Each contrast ``{mode: coefficient}`` of the modes' success with its own 95 %
    bootstrap CI, e.g. ``{"full": 1, "comm": -1, "distance": -1, "independent": 1}`` (an
    interaction); keys as in ``contrasts``.

    ``successes[mode]`` (S_mode, E) holds the per-episode success (0 or 1) of each training
    seed of the mode on the same E fixed test episodes: column e is the same start cells and
    exploration draws for every seed of every mode. A mode's success is the mean over its
    seeds of each seed's success rate; ``mean`` is the sum of the coefficients times them.

    What one bootstrap resample redraws, with replacement:
      * the test episodes: one draw of E episode indices, *shared* by every mode and seed
        (the pairing by test episode set: every mode of a contrast is scored on the same
        resampled episodes, so the episodes' difficulty cancels);
      * the training seeds: S_mode seeds of each mode, independently between modes (the
        seeds of two modes are unrelated training runs).
    Every mode of ``successes`` is resampled, in its order, whether a contrast uses it or
    not. ``ci95`` is the percentile interval of the resampled contrasts; ``ci95_seeds_only``
    keeps the episode set fixed and redraws the seeds only (the spread due to training
    alone). ``established``: ``ci95`` excludes 0.
    """
    rates = {m: np.asarray(a, dtype=np.float32) for m, a in successes.items()}
    shapes = {a.shape[1] for a in rates.values() if a.ndim == 2}
    if len(shapes) != 1 or any(a.ndim != 2 or len(a) == 0 for a in rates.values()):
        raise ValueError(
            "mode contrasts need (seeds, E) arrays with the same E, got "
            f"{ {m: a.shape for m, a in rates.items()} }"
        )
    for name, coefficients in contrasts.items():
        if not coefficients or not set(coefficients) <= set(rates):
            raise ValueError(
                f"contrast {name!r} uses modes {sorted(coefficients)}; available: {sorted(rates)}"
            )
    episodes = shapes.pop()
    rng = np.random.default_rng(seed)
    both = {m: [] for m in rates}
    seeds_only = {m: [] for m in rates}
    for start in range(0, n_resamples, chunk):
        size = min(chunk, n_resamples - start)
        weights = _resampled_episode_weights(rng, size, episodes)  # (R, E)
        for mode, values in rates.items():
            count = len(values)
            picks = rng.multinomial(count, np.full(count, 1 / count), size=size)  # (R, S)
            per_seed = weights @ values.T / episodes  # (R, S): each seed on the resampled episodes
            both[mode].append((picks * per_seed).sum(axis=1) / count)
            seeds_only[mode].append(picks @ values.mean(axis=1) / count)
    tail = (1 - CONFIDENCE) / 2
    result = {}
    for name, coefficients in contrasts.items():
        spread = fixed = mean = 0.0
        for mode, coefficient in coefficients.items():
            spread = spread + coefficient * np.concatenate(both[mode])
            fixed = fixed + coefficient * np.concatenate(seeds_only[mode])
            mean = mean + coefficient * rates[mode].astype(np.float64).mean(axis=1).mean()
        low, high = np.quantile(spread, [tail, 1 - tail])
        fixed_low, fixed_high = np.quantile(fixed, [tail, 1 - tail])
        result[name] = {
            "coefficients": dict(coefficients),
            "mean": float(mean),
            "ci95": [float(low), float(high)],
            "ci95_seeds_only": [float(fixed_low), float(fixed_high)],
            "established": bool(low > 0 or high < 0),
            "seeds": {mode: len(rates[mode]) for mode in coefficients},
            "episodes": episodes,
        }
    return result


def mode_differences(
    successes: dict[str, np.ndarray],
    n_resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
    chunk: int = 1_000,
) -> dict[str, dict[str, float | list | bool | int | str]]:
    """Difference of success for each pair of modes, later minus earlier in the order of
    ``successes``, with its own 95 % bootstrap CI; keys ``"<later>_minus_<earlier>"``.

    The contrasts ``later − earlier`` of :func:`mode_contrasts` (its resampling: test
    episodes shared by every mode, seeds redrawn within each mode), each entry with
    ``first`` (later), ``second`` (earlier) and ``seeds`` as [S_later, S_earlier].
    """
    names = list(successes)
    pairs = {
        f"{later}_minus_{earlier}": (later, earlier)
        for k, earlier in enumerate(names)
        for later in names[k + 1 :]
    }
    contrasts = mode_contrasts(
        successes,
        {key: {later: 1.0, earlier: -1.0} for key, (later, earlier) in pairs.items()},
        n_resamples,
        seed,
        chunk,
    )
    result = {}
    for key, (later, earlier) in pairs.items():
        entry = contrasts[key]
        result[key] = {"first": later, "second": earlier} | {
            k: entry[k] for k in ("mean", "ci95", "ci95_seeds_only", "established")
        }
        result[key] |= {"seeds": [entry["seeds"][later], entry["seeds"][earlier]]}
        result[key]["episodes"] = entry["episodes"]
    return result


def average_ranks(values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Ranks (..., n) from 1 along the last axis of ``values`` (..., n); tied values share
    the mean of the ranks they occupy (e.g. [10, 20, 20, 30] -> [1, 2.5, 2.5, 4])."""
    v = np.asarray(values, dtype=np.float64)
    below = (v[..., None, :] < v[..., :, None]).sum(axis=-1)
    equal = (v[..., None, :] == v[..., :, None]).sum(axis=-1)  # itself included
    return below + (equal + 1) / 2


def _rank_correlations(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman's rho along the last axis of x, y (..., n); NaN where either is constant."""
    rx, ry = average_ranks(x), average_ranks(y)
    rx = rx - rx.mean(axis=-1, keepdims=True)
    ry = ry - ry.mean(axis=-1, keepdims=True)
    scale = np.sqrt((rx * rx).sum(axis=-1) * (ry * ry).sum(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(scale > 0, (rx * ry).sum(axis=-1) / scale, np.nan)


def spearman(x: Sequence[float], y: Sequence[float]) -> float | None:
    """Spearman's rank correlation of paired samples x, y (n,): the Pearson correlation of
    their average ranks; None if either sample is constant (the correlation is undefined)."""
    rho = float(_rank_correlations(np.asarray(x, float), np.asarray(y, float)))
    return None if np.isnan(rho) else rho


def spearman_interval(
    x: Sequence[float],
    y: Sequence[float],
    n_resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> dict[str, Any]:
    """:func:`spearman` of x, y (n,) with a percentile bootstrap 95 % interval: each resample
    draws n pairs with replacement. A resample in which x or y is constant has no
    correlation: it is left out and counted in ``undefined_resamples`` (``ci95`` is None
    if every resample is)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(
            f"spearman_interval needs two samples of one length, got {x.shape}, {y.shape}"
        )
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(x), size=(n_resamples, len(x)))
    resampled = _rank_correlations(x[picks], y[picks])  # (n_resamples,)
    defined = resampled[~np.isnan(resampled)]
    tail = (1 - CONFIDENCE) / 2
    interval = np.quantile(defined, [tail, 1 - tail]).tolist() if defined.size else None
    return {
        "rho": spearman(x, y),
        "ci95": interval,
        "n": len(x),
        "resamples": n_resamples,
        "undefined_resamples": int(n_resamples - defined.size),
    }
