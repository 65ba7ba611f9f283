"""The memory study's tests on the 40 held-out maps, run on exported memory agents: success,
the channel interventions, the causal influence of the message on the receiver (CIC), what
the message says on and off the target, and the homing share (while the partner stands on
the target, does a move bring the agent closer?), with the beacon explorer's homing share
for comparison."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch
from analysis.arrivals import homing_counts
from analysis.baselines import POLICIES
from analysis.episodes import recorded_episodes
from analysis.held_out import held_out_maps
from analysis.information import BIN_COUNTS, causal_influence, message_bins
from analysis.interventions import intervene, intervention_table, real_steps
from analysis.map_sets import HELD_OUT_MAP_SEEDS
from rollout import EVAL_EPSILON, EVAL_SEED, EpisodeResults, run_episodes
from vector_env import DISTANCE_INDEX, MESSAGE_INDEX, TARGET, VectorMultiAgentEnv

from studies.memory.agents import memory_policy

CONDITIONS = {"greedy": 0.0, "eps": EVAL_EPSILON}
CHANNELS = {
    "message": (MESSAGE_INDEX, ("comm", "full")),
    "distance": (DISTANCE_INDEX, ("distance", "full")),
}
PROBES = ("same_step", "constant_mean", "constant_0", "constant_1")


def manhattan_distances(grid: np.ndarray) -> np.ndarray:
    """Manhattan distance (H, W) of every cell to the target (the homing measure here)."""
    target = np.argwhere(np.asarray(grid) == TARGET)[0]
    return np.abs(np.indices(np.shape(grid)) - target[:, None, None]).sum(axis=0)


def message_on_off(results: EpisodeResults, target: tuple[int, int]) -> np.ndarray:
    """(sum on the target, count on, sum off, count off) of the messages sent (4,)."""
    positions = results.trajectories["positions"][:, :-1]
    on = (np.abs(positions - np.asarray(target)).sum(-1) == 0) & real_steps(results)[..., None]
    off = ~on & real_steps(results)[..., None]
    sent = np.nan_to_num(results.trajectories["messages"])
    return np.array([sent[on].sum(), on.sum(), sent[off].sum(), off.sum()], dtype=np.float64)


def memory_states(agent: torch.nn.Module, observations: np.ndarray, actions: np.ndarray) -> tuple:
    """Replay one agent's recorded episodes: observations (E, T + 1, D) as received and
    actions (E, T) as taken (−1 after the end) -> the previous action (E, T) and the hidden
    state before each step (E, T, H), from which the agent acted at that step."""
    episodes, horizon = actions.shape
    h = agent.initial_state(episodes)
    previous = np.concatenate([np.full((episodes, 1), -1), actions[:, :-1]], axis=1)
    states = []
    with torch.inference_mode():
        for t in range(horizon):
            states.append(h)
            obs = torch.from_numpy(np.ascontiguousarray(observations[:, t], dtype=np.float32))
            _, _, h = agent(obs, torch.from_numpy(previous[:, t].astype(np.int64)), h)
    return previous, torch.stack(states, dim=1).numpy()


def memory_cic(
    agents: tuple, recorded: EpisodeResults, epsilon: float, max_states: int = 2000, seed: int = 0
) -> dict[str, float]:
    """CIC (bits, ``analysis.information.causal_influence``) of each sender's message on the
    receiver's ε-greedy policy, mean of the two directions, per bin count: the receiver's
    previous action and hidden state are held at the recorded ones while each bin centre is
    fed as the message of that step (at most ``max_states`` receiver steps per direction)."""
    trajectories = recorded.trajectories
    observations, actions = trajectories["observations"], trajectories["actions"]
    valid = actions[..., 0] >= 0  # (E, T)
    rng = np.random.default_rng(seed)
    steps = np.flatnonzero(valid.ravel())  # the real steps, the same for both receivers
    chosen_per_receiver = []
    for receiver, agent in enumerate(agents):
        previous, hidden = memory_states(
            agent, observations[:, :, receiver], actions[..., receiver]
        )
        rows = steps
        if len(rows) > max_states:
            rows = np.sort(rng.choice(steps, max_states, replace=False))
        pick = np.unravel_index(rows, valid.shape)
        chosen_per_receiver.append(
            (agent, observations[:, :-1, receiver][pick], previous[pick], hidden[pick])
        )
    result = {}
    for bins in BIN_COUNTS:
        sent = message_bins(np.nan_to_num(trajectories["messages"]), bins)  # (E, T, 2)
        values = []
        for receiver, (agent, obs, previous, hidden) in enumerate(chosen_per_receiver):
            p_m = np.bincount(sent[..., 1 - receiver][valid], minlength=bins) / valid.sum()
            fixed_previous, fixed_hidden = torch.from_numpy(previous), torch.from_numpy(hidden)

            def q_function(
                x: np.ndarray, agent=agent, p=fixed_previous, h=fixed_hidden
            ) -> np.ndarray:
                with torch.inference_mode():
                    return agent(torch.from_numpy(x), p, h)[0].numpy()

            values.append(causal_influence(q_function, obs, MESSAGE_INDEX, p_m, epsilon))
        result[f"K{bins}"] = float(np.mean(values))
    return result


def held_out_results(agents: tuple, mode: str, episodes: int, max_steps: int) -> dict[str, Any]:
    """Success, interventions, CIC (on the greedy episodes, where the receiver hears a
    message), message encoding and homing of one run on the held-out maps."""
    success = {c: [] for c in CONDITIONS}
    cic = {f"K{bins}": [] for bins in BIN_COUNTS} if mode in CHANNELS["message"][1] else {}
    probes = {
        f"{channel}.{kind}": {c: [] for c in CONDITIONS}
        for channel, (_, modes) in CHANNELS.items()
        if mode in modes
        for kind in PROBES
    }
    homing, encoding = np.zeros(3), np.zeros(4)
    for map_seed, grid in zip(HELD_OUT_MAP_SEEDS, held_out_maps(), strict=True):
        env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
        for label, epsilon in CONDITIONS.items():
            policy = functools.partial(memory_policy, agents, env, epsilon, EVAL_SEED + map_seed)
            real = recorded_episodes(env, policy(), episodes, seed=EVAL_SEED)
            success[label].append(float(real.successes.mean()))
            if label == "greedy" and cic:
                for key, value in memory_cic(agents, real, EVAL_EPSILON, seed=map_seed).items():
                    cic[key].append(value)
            if label == "eps":
                homing += homing_counts(real, manhattan_distances(grid))
                encoding += message_on_off(real, env.target_position)
            received = real.trajectories["observations"][:, :-1][real_steps(real)]  # (M, 2, D)
            for name in probes:
                channel, kind = name.split(".")
                index = CHANNELS[channel][0]
                mean = float(np.ascontiguousarray(received[..., index]).mean())  # the run's mean
                table = intervention_table(kind, real, index, constant=mean, seed=map_seed)
                probed = run_episodes(
                    env, intervene(policy(), env, table, index), episodes, seed=EVAL_SEED
                )
                probes[name][label].append(float(probed.successes.mean()) - success[label][-1])
    return {
        "success": {c: float(np.mean(v)) for c, v in success.items()},
        "success_per_map": success,
        "interventions": {
            n: {c: float(np.mean(v)) for c, v in p.items()} for n, p in probes.items()
        },
        "homing_counts_eps": homing.tolist(),
        "message_on_off_eps": encoding.tolist(),
    } | ({"cic_greedy_episodes": {k: float(np.mean(v)) for k, v in cic.items()}} if cic else {})


def beacon_homing(episodes: int, max_steps: int) -> list[float]:
    """The beacon explorer's homing counts (closer, farther, neither) on the held-out maps."""
    counts = np.zeros(3)
    for map_seed, grid in zip(HELD_OUT_MAP_SEEDS, held_out_maps(), strict=True):
        env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
        policy = POLICIES["beacon_explorer"](grid, EVAL_SEED + map_seed)
        counts += homing_counts(
            recorded_episodes(env, policy, episodes, seed=EVAL_SEED), manhattan_distances(grid)
        )
    return counts.tolist()
