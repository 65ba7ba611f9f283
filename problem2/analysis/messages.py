"""What the learned message says: its distribution per agent, its correlation with what the
sender sees and where it stands, and its mean per grid cell. All functions read recorded
episodes (``rollout.EpisodeResults`` with trajectories)."""

from __future__ import annotations

import numpy as np
from rollout import EpisodeResults
from vector_env import TARGET

from analysis.episodes import target_distances

AGENTS = ("A", "B")
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
HISTOGRAM_BINS = 10
FEATURE_DESCRIPTIONS = {
    "on_target": "the sender stands on the target (binary)",
    "sees_target": "the target lies in the sender's 3x3 patch, its own cell included (binary)",
    "target_distance": "the sender's shortest-path (BFS) distance to the target, in steps",
    "agent_distance": "Euclidean distance between the two agents, in cells",
    "time_step": "step of the episode at which the message is sent (0-based)",
}


def _sent_messages(results: EpisodeResults) -> tuple[np.ndarray, np.ndarray]:
    """Messages sent during the episodes (E, T, 2) and the mask (E, T) of real steps."""
    if results.trajectories is None:
        raise ValueError("message analysis needs recorded episodes (record=True)")
    messages = results.trajectories["messages"]
    return messages, ~np.isnan(messages[..., 0])


def message_distribution(results: EpisodeResults) -> dict[str, dict]:
    """Per agent: count, mean, std, min, max, quantiles and a 10-bin histogram on [0, 1]
    of every message sent."""
    messages, valid = _sent_messages(results)
    distribution = {}
    for index, agent in enumerate(AGENTS):
        sent = messages[..., index][valid].astype(np.float64)
        counts, edges = np.histogram(sent, bins=HISTOGRAM_BINS, range=(0.0, 1.0))
        distribution[agent] = {
            "count": int(sent.size),
            "mean": float(sent.mean()),
            "std": float(sent.std()),
            "min": float(sent.min()),
            "max": float(sent.max()),
            "quantiles": {
                f"{q:.2f}": float(v)
                for q, v in zip(QUANTILES, np.quantile(sent, QUANTILES), strict=True)
            },
            "histogram": {"bin_edges": edges.tolist(), "counts": counts.tolist()},
        }
    return distribution


def _pearson(x: np.ndarray, y: np.ndarray) -> float | None:
    """Pearson correlation of two samples (n,); None if either is constant."""
    x, y = x - x.mean(), y - y.mean()
    scale = np.sqrt((x * x).sum() * (y * y).sum())
    return float((x * y).sum() / scale) if scale > 1e-12 else None


def message_features(results: EpisodeResults, grid: np.ndarray) -> dict[str, np.ndarray]:
    """Each feature of ``FEATURE_DESCRIPTIONS`` at every step (E, T, 2) (sender's view)."""
    trajectories = results.trajectories
    if trajectories is None:
        raise ValueError("message analysis needs recorded episodes (record=True)")
    horizon = trajectories["messages"].shape[1]
    positions = trajectories["positions"][:, :horizon]  # (E, T, 2, 2) before each step
    patches = trajectories["observations"][:, :horizon, :, :9]  # (E, T, 2, 9)
    target = np.argwhere(grid == TARGET)[0]
    offset = positions[:, :, 0] - positions[:, :, 1]
    between = np.hypot(offset[..., 0], offset[..., 1])  # (E, T)
    return {
        "on_target": np.all(positions == target, axis=-1).astype(np.float64),
        "sees_target": np.any(patches == TARGET, axis=-1).astype(np.float64),
        "target_distance": target_distances(grid)[positions[..., 0], positions[..., 1]].astype(
            np.float64
        ),
        "agent_distance": np.repeat(between[..., None], 2, axis=-1),
        "time_step": np.broadcast_to(
            np.arange(horizon, dtype=np.float64)[None, :, None], between.shape + (2,)
        ),
    }


def message_correlations(results: EpisodeResults, grid: np.ndarray) -> dict[str, dict]:
    """Per agent and feature: Pearson ``r`` between the message sent and the feature (None
    if either is constant), plus, for binary features, the mean message when the feature
    holds and when it does not and how often it holds."""
    messages, valid = _sent_messages(results)
    features = message_features(results, grid)
    correlations: dict[str, dict] = {}
    for index, agent in enumerate(AGENTS):
        sent = messages[..., index][valid].astype(np.float64)
        entry = {}
        for name, values in features.items():
            feature = values[..., index][valid]
            item: dict = {"r": _pearson(sent, feature)}
            if name in ("on_target", "sees_target"):
                holds = feature > 0.5
                item["share_true"] = float(holds.mean())
                item["mean_if_true"] = float(sent[holds].mean()) if holds.any() else None
                item["mean_if_false"] = float(sent[~holds].mean()) if (~holds).any() else None
            entry[name] = item
        correlations[agent] = entry
    return correlations


def mean_message_per_cell(results: EpisodeResults, grid_shape: tuple[int, int]) -> np.ndarray:
    """Mean message (2, H, W) that each agent sent from each cell; NaN where it never was."""
    messages, valid = _sent_messages(results)
    rows, cols = grid_shape
    horizon = messages.shape[1]
    positions = results.trajectories["positions"][:, :horizon]
    means = np.full((2, rows, cols), np.nan)
    for index in range(2):
        cells = (positions[..., index, 0] * cols + positions[..., index, 1])[valid]
        totals = np.bincount(cells, weights=messages[..., index][valid], minlength=rows * cols)
        counts = np.bincount(cells, minlength=rows * cols)
        with np.errstate(invalid="ignore", divide="ignore"):
            means[index] = np.where(counts > 0, totals / counts, np.nan).reshape(rows, cols)
    return means
