"""Causal tests of the observation's input channels: what happens to success when the
message or the distance an agent receives is replaced by something else.

An intervention is a table ``(E, T, 2)`` of the values the two agents receive on channel
``index`` at each step of each test episode; :func:`intervene` wraps a policy so that it
reads the table instead of the real value, and nothing else changes. Tables are built from
a recorded run of the same test episodes with the real input (same start cells), so "another
episode" and "a random step" mean episodes and steps that really occurred.

Kinds (``INTERVENTIONS``), each with its question:

* ``real``: the input as the environment delivers it.
* ``same_step``: at step t, the value another episode received at its step t (an episode
  still running then). Keeps whatever depends on the time step alone (a clock).
* ``random_step``: a value received at a random step of a random episode. Keeps only the
  distribution of values.
* ``shuffled_time``: the episode's own received values, permuted in time. Keeps the
  episode's values but not when they came.
* ``constant_mean``: the mean received value of the mode (over its seeds), at every step.
* ``constant_0`` / ``constant_1``: 0 or 1 at every step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from rollout import EpisodeResults, PolicyFn
from vector_env import VectorMultiAgentEnv

INTERVENTIONS = {
    "real": "the input as delivered",
    "same_step": "the value another episode received at the same step",
    "random_step": "the value received at a random step of a random episode",
    "shuffled_time": "the episode's own received values, permuted in time",
    "constant_mean": "a constant: the mean received value of the mode's real test episodes",
    "constant_0": "the constant 0",
    "constant_1": "the constant 1",
}
CHANNEL_INTERVENTIONS = {
    "message": tuple(INTERVENTIONS),
    # every probe that keeps the distance in its range: content, clock and presence
    "distance": ("real", "same_step", "random_step", "shuffled_time", "constant_mean"),
}
CHANNEL_MODES = {"message": ("comm", "full"), "distance": ("distance", "full")}


def received_values(recorded: EpisodeResults, index: int) -> np.ndarray:
    """Values (E, T, 2) received on observation element ``index`` before each step (held
    after an episode's end)."""
    if recorded.trajectories is None:
        raise ValueError("interventions need a recorded real run (record=True)")
    return recorded.trajectories["observations"][:, :-1, :, index]


def real_steps(recorded: EpisodeResults) -> np.ndarray:
    """Mask (E, T): the step was taken in the recorded episode."""
    horizon = recorded.trajectories["actions"].shape[1]
    return np.arange(horizon)[None, :] < recorded.lengths[:, None]


def mean_received(recorded_runs: list[EpisodeResults], index: int) -> float:
    """Mean value received on element ``index`` over the real steps of several runs."""
    values = [received_values(r, index)[real_steps(r)] for r in recorded_runs]
    return float(np.concatenate(values).mean())


def intervention_table(
    kind: str, recorded: EpisodeResults, index: int, constant: float = 0.0, seed: int = 0
) -> np.ndarray | None:
    """The values (E, T, 2) float32 that ``kind`` feeds on element ``index`` in the E test
    episodes of ``recorded`` (None for ``real``). ``constant`` is the value of
    ``constant_mean``; ``seed`` fixes the random choices."""
    if kind not in INTERVENTIONS:
        raise ValueError(f"unknown intervention {kind!r}; use one of {tuple(INTERVENTIONS)}")
    if kind == "real":
        return None
    received = received_values(recorded, index)  # (E, T, 2)
    episodes, horizon, _ = received.shape
    rng = np.random.default_rng(seed)
    if kind.startswith("constant"):
        value = {"constant_mean": constant, "constant_0": 0.0, "constant_1": 1.0}[kind]
        return np.full(received.shape, value, dtype=np.float32)
    steps = np.arange(horizon)
    mask = real_steps(recorded)
    if kind == "random_step":
        pool = received[mask]  # (M, 2), each row one real step of one episode
        return pool[rng.integers(len(pool), size=(episodes, horizon))].astype(np.float32)
    if kind == "shuffled_time":
        lengths = np.maximum(recorded.lengths, 1)
        keys = np.where(mask, rng.random((episodes, horizon)), np.inf)
        order = np.argsort(keys, axis=1)  # a random order of each episode's real steps first
        source = order[np.arange(episodes)[:, None], steps[None, :] % lengths[:, None]]
        return np.take_along_axis(received, source[..., None], axis=1).astype(np.float32)
    table = np.empty_like(received, dtype=np.float32)  # same_step
    for t in steps:
        running = np.flatnonzero(mask[:, t])
        if running.size < 2:  # nobody else ran this long: the values held at the end
            running = np.arange(episodes)
        donors = running[rng.integers(running.size, size=episodes)]
        clash = donors == np.arange(episodes)
        donors[clash] = running[(np.searchsorted(running, donors[clash]) + 1) % running.size]
        table[:, t] = received[donors, t]
    return table


def stack_tables(tables: list[np.ndarray | None], episodes: int, setting) -> np.ndarray:
    """One table (K·E, T, 2) for K blocks stepped together; NaN (keep the real value) for
    a block without a table."""
    shape = (episodes, setting.max_steps, 2)
    return np.concatenate(
        [np.full(shape, np.nan, dtype=np.float32) if t is None else t for t in tables]
    )


def intervene(
    policy_fn: PolicyFn, env: VectorMultiAgentEnv, table: np.ndarray | None, index: int
) -> PolicyFn:
    """``policy_fn`` reading ``table[c, t]`` (N, T, 2) on element ``index`` in copy c of
    ``env`` at its step t, the real value where the table holds NaN; each copy runs one
    episode (the run fits in one round)."""
    if table is None:
        return policy_fn
    if len(table) != env.n_envs:
        raise ValueError(f"intervention table for {len(table)} copies, env has {env.n_envs}")
    horizon = table.shape[1]
    flat_table = table.reshape(-1, 2)  # row c·T + t: copy c at step t
    flat_keep = np.isnan(flat_table)
    row_starts = np.arange(len(table)) * horizon

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows = row_starts + np.minimum(env.steps, horizon - 1)
        changed = obs.copy()
        values = np.take(flat_table, rows, axis=0)
        changed[:, :, index] = np.where(np.take(flat_keep, rows, axis=0), obs[:, :, index], values)
        return policy_fn(changed, positions)

    return act


def intervention_wrap(
    tables: list[dict[int, np.ndarray | None]], episodes: int, setting
) -> Callable[[PolicyFn, VectorMultiAgentEnv, range], PolicyFn]:
    """The ``wrap`` of ``MultiAgentEvaluator.run_blocks`` that feeds block k the tables
    ``tables[k]`` ({observation index: table (E, T, 2)}; a block without one reads the real
    input)."""

    def wrap(policy: PolicyFn, env: VectorMultiAgentEnv, group: range) -> PolicyFn:
        for index in sorted({i for k in group for i in tables[k]}):
            stacked = stack_tables([tables[k].get(index) for k in group], episodes, setting)
            policy = intervene(policy, env, stacked, index)
        return policy

    return wrap


def intervention_test(
    evaluator,
    num_episodes: int = 1000,
    recorded: dict[str, EpisodeResults] | None = None,
    channels: tuple[str, ...] = ("message", "distance"),
    constants: dict[tuple[str, str], float] | None = None,
    seed: int = 0,
) -> dict[str, dict[str, dict[str, float]]]:
    """Success rate of ``evaluator``'s policy (an ``analysis.evaluator.MultiAgentEvaluator``)
    under every intervention on each of ``channels`` beside the real input: ``{channel:
    {condition: {kind: rate}}}``. One batch: every channel, condition and intervention
    stepped together on the same test episodes and exploration draws as ``recorded`` (the
    real greedy and ε-greedy runs; run here if not given). ``constants[(channel,
    condition)]`` is the value of ``constant_mean`` (default: this pair's own mean received
    value)."""
    recorded = recorded or evaluator.run_conditions(num_episodes)
    first = evaluator.setting.obs_window**2
    indices = {"message": first, "distance": first + 1}
    constants = constants or {
        (channel, name): mean_received([recorded[name]], indices[channel])
        for channel in channels
        for name in evaluator.conditions
    }
    blocks = [
        (channel, name, kind)
        for channel in channels
        for name in evaluator.conditions
        for kind in CHANNEL_INTERVENTIONS[channel][1:]
    ]
    tables = [
        {
            indices[channel]: intervention_table(
                kind,
                recorded[name],
                indices[channel],
                constants[channel, name],
                seed * 100 + number,
            )
        }
        for number, (channel, name, kind) in enumerate(blocks)
    ]
    epsilons = [evaluator.conditions[name] for _, name, _ in blocks]
    wrap = intervention_wrap(tables, num_episodes, evaluator.setting)
    runs = evaluator.run_blocks(num_episodes, epsilons, wrap)
    result = {
        channel: {
            name: {"real": float(recorded[name].successes.mean())} for name in evaluator.conditions
        }
        for channel in channels
    }
    for (channel, name, kind), run in zip(blocks, runs, strict=True):
        result[channel][name][kind] = float(run.successes.mean())
    return result


def channel_verdict(deltas: dict[str, dict]) -> str:
    """What the agents use of a channel, from the Δsuccess (intervention − real) seed
    statistics of each intervention (``mean``, ``ci95``): a CI entirely below 0 is a loss.

    * ``content``: a value from another episode at the same step hurts;
    * ``clock``: it does not, but values from other steps (random step or shuffled in time)
      do: what matters is how the value changes with time, not the episode;
    * ``presence``: only constants hurt: the agents need a value in the usual range;
    * ``none``: no intervention lowers success."""

    def hurts(kind: str) -> bool:
        entry = deltas.get(kind)
        return bool(entry and entry.get("ci95") and entry["ci95"][1] < 0)

    if hurts("same_step"):
        return "content"
    if hurts("random_step") or hurts("shuffled_time"):
        return "clock"
    if any(hurts(k) for k in ("constant_mean", "constant_0", "constant_1")):
        return "presence"
    return "none"


def raising(deltas: dict[str, dict]) -> list[str]:
    """The interventions whose Δsuccess CI lies entirely above 0 (they help the agents)."""
    return [k for k, v in deltas.items() if v.get("ci95") and v["ci95"][0] > 0]


VERDICTS = {
    "content": "success drops when the value comes from another episode at the same step: "
    "the agents use what this episode's value says",
    "clock": "a value from another episode at the same step does as well as the real one, "
    "but values from other steps do not: the channel works as a clock",
    "presence": "only constants lower success: the agents need a value in the usual range, "
    "not its content",
    "none": "no intervention lowers success (95 % CI over seeds): no evidence the channel is used",
}


def message_verdict(causal: dict[str, dict], epsilon: float) -> tuple[bool, str]:
    """(used, plain-language verdict) from the real − shuffled success difference and its
    95 % bootstrap CI over seeds (with one seed, the episode-level CI). The message counts
    as used when the CI of the ε-greedy condition lies above 0."""
    parts, used = [], False
    for name in ("greedy", "eps"):
        diff = causal[name]["real_minus_shuffled"]
        low, high = diff["ci95"]
        label = "greedy" if name == "greedy" else f"ε = {epsilon}"
        span = f"real − shuffled = {diff['mean']:+.3f} (95 % CI [{low:+.3f}, {high:+.3f}])"
        if low > 0:
            parts.append(f"{label}: {span}, above 0: the partner relies on its content")
            used = used or name == "eps"
        elif high < 0:
            parts.append(
                f"{label}: {span}, below 0: a message from another episode does better than "
                "the real one (a random input can break a greedy policy's loops)"
            )
        else:
            parts.append(f"{label}: {span} includes 0")
    head = (
        "The message carries information the partner uses."
        if used
        else "No evidence that the message carries anything the partner uses: replacing it "
        "by a message from another episode does not lower success."
    )
    return used, f"{head} " + "; ".join(parts) + "."


def causal_message_test(message_test: dict, epsilon: float) -> dict[str, Any]:
    """The message test as ``communication_analysis.json``'s ``causal`` entry, which the
    comparison table's message section reads: real, shuffled (= ``same_step``) and zeroed
    (= ``constant_0``) success, real minus each, and the verdict."""
    causal: dict[str, Any] = {}
    for condition in ("greedy", "eps"):
        success, delta = (
            message_test[condition]["success"],
            message_test[condition]["delta_success"],
        )
        causal[condition] = {
            "real": success["real"],
            "shuffled": success["same_step"],
            "zeroed": success["constant_0"],
        }
        for old, new in (("shuffled", "same_step"), ("zeroed", "constant_0")):
            flipped = {**delta[new]}
            flipped["mean"] = -delta[new]["mean"]
            flipped["ci95"] = [-delta[new]["ci95"][1], -delta[new]["ci95"][0]]
            flipped["iqm"] = -delta[new]["iqm"]
            flipped["per_seed"] = [None if v is None else -v for v in delta[new]["per_seed"]]
            causal[condition][f"real_minus_{old}"] = flipped
    used, causal["verdict"] = message_verdict(causal, epsilon)
    causal["message_used"] = used
    return causal
