"""Why one step of memory is enough on a known map: ablations, interventions, behaviour.

    python -m studies.one_step.why --train     # train the ablations, then measure
    python -m studies.one_step.why             # measure from the trained batches

On the open-ground maps (``MAPS``), independent agents (neither channel) only:

1. **Trained ablations**: one-step memory agents that keep the previous move alone or the
   previous observation alone (``agents.memory_mask``'s ``keep``), seeds 641-645, the main
   recipe, into ``memory_panel/ablations/<part>/map<K>/``.
2. **Interventions at test time** on the memory panel's agents (both memory inputs): the
   previous move replaced by a uniformly random move or by another episode's at the same
   step, the previous observation replaced by another episode's at the same step or by zeros
   (as at an episode start); success change, paired by seed.
3. **Behaviour**, memoryless (the map panel's agents) against one-step memory: how often an
   agent off the target undoes its previous move (a step back where it came from), how often
   it repeats it, and the share of failed episodes; the episodes of seed 641 on the first map
   drawn side by side.
4. **The memoryless channels as stand-ins for memory**: the map panel's test-time
   replacements of the distance and the message (another episode's value at the same step,
   a random step's, the episode's own values shuffled in time, the run's mean), read from
   ``panel.json``.

Every test uses the map panel's 1000 test episodes per seed and its exploration draws.
Outputs: ``memory_panel/why/why.json`` and ``why.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
import train
from analysis.episodes import recorded_episodes
from analysis.plots import EpisodeTrace, draw_map, draw_paths, episode_trace, save_figure
from analysis.stats import seed_statistics
from matplotlib.figure import Figure
from rollout import EVAL_SEED, run_episodes
from settings import TrainConfig, available_cores
from vector_env import TARGET, VectorMultiAgentEnv

from studies.memory.agents import memory_policy
from studies.one_step.agents import OneStepMemoryTrainer
from studies.one_step.panel import (
    CONDITIONS,
    MEMORY_PANEL_DIR,
    SEEDS,
    exploration,
    pair_policy,
    read_batch,
)
from studies.panel import PANEL_DIR
from studies.staging import run_command

MAPS = (4, 1, 6)  # the panel's maps with the target in open ground, map 4 first (the figure)
MODE = "independent"
WHY_DIR = MEMORY_PANEL_DIR / "why"
ABLATIONS_DIR = MEMORY_PANEL_DIR / "ablations"
REVERSE = np.array([1, 0, 3, 2, 4])  # Up <-> Down, Left <-> Right; Stay has no reverse
FONT = 8  # points at the printed width
INTERVENTIONS = ("move_random", "move_other_episode", "observation_other_episode", "zeros")
CHANNEL_PROBES = ("same_step", "random_step", "shuffled_time", "constant_mean")


class MoveOnlyTrainer(OneStepMemoryTrainer):
    memory_inputs = ("move",)


class ObservationOnlyTrainer(OneStepMemoryTrainer):
    memory_inputs = ("observation",)


ABLATIONS = {"move": MoveOnlyTrainer, "observation": ObservationOnlyTrainer}


def train_batches(trainers: dict[str, type], mode: str, output_dir: Path, workers: int) -> None:
    """For each named trainer and each of ``MAPS``, one batch of ``mode`` over ``SEEDS`` with the
    main recipe into ``output_dir/<name>/map<K>`` (the ablations here, the clock control's)."""
    for name, trainer_class in trainers.items():
        for map_seed in MAPS:
            settings = dict(mode=mode, map_seed=map_seed, seed=SEEDS[0], num_seeds=len(SEEDS))
            folder = output_dir / name / f"map{map_seed}"
            cfg = TrainConfig(**settings, overwrite=True, output_dir=str(folder), workers=workers)
            train.main(cfg=cfg, trainer_class=trainer_class)


class Intervened:
    """A memory-contract agent whose memory inputs are replaced before each step: the
    previous move (random, or another copy's: another episode at the same step) or the
    previous observation (another copy's, or zeros)."""

    def __init__(self, agent: torch.nn.Module, kind: str, seed: int) -> None:
        self.agent, self.kind = agent, kind
        self.generator = torch.Generator().manual_seed(seed)

    def initial_state(self, n: int) -> torch.Tensor:
        return self.agent.initial_state(n)

    def __call__(self, obs: torch.Tensor, prev: torch.Tensor, h: torch.Tensor) -> tuple:
        started = prev >= 0
        if self.kind == "move_random":
            drawn = torch.randint(0, 5, prev.shape, generator=self.generator)
            prev = torch.where(started, drawn, prev)
        elif self.kind == "move_other_episode":
            other = prev.roll(1, 0)  # where that episode is just starting, the agent's own
            prev = torch.where(started & (other >= 0), other, prev)
        elif self.kind == "observation_other_episode":
            h = torch.where(started[:, None], h.roll(1, 0), h)
        elif self.kind == "zeros":
            h = torch.zeros_like(h)
        return self.agent(obs, prev, h)


def load_pair(models_dir: Path, seed: int) -> tuple:
    return tuple(torch.jit.load(str(models_dir / f"{MODE}_seed{seed}_agent_{a}.pt")) for a in "AB")


def success_rates(models_dir: Path, grid: np.ndarray, max_steps: int, episodes: int) -> dict:
    """Per condition the success rate (S,) of each seed's pair."""
    rates = {c: [] for c in CONDITIONS}
    for seed in SEEDS:
        agents = load_pair(models_dir, seed)
        for condition, epsilon in CONDITIONS.items():
            env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
            policy = pair_policy(agents, env, epsilon)
            rates[condition].append(
                float(run_episodes(env, policy, episodes, EVAL_SEED).successes.mean())
            )
    return rates


def intervention_deltas(
    models_dir: Path, grid: np.ndarray, max_steps: int, episodes: int, real: dict
) -> dict:
    """Per intervention and condition the success change (S,) against the real memory, whose
    success rates ``real`` (:func:`success_rates` of the same pairs) already measured."""
    deltas = {k: {c: [] for c in CONDITIONS} for k in INTERVENTIONS}
    for index, seed in enumerate(SEEDS):
        agents = load_pair(models_dir, seed)
        for condition, epsilon in CONDITIONS.items():
            env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
            for kind in INTERVENTIONS:
                wrapped = tuple(Intervened(a, kind, seed + i) for i, a in enumerate(agents))
                policy = memory_policy(wrapped, env, draws=exploration(env, epsilon))
                probed = run_episodes(env, policy, episodes, EVAL_SEED)
                change = float(probed.successes.mean() - real[condition][index])
                deltas[kind][condition].append(change)
    return deltas


def move_shares(actions: np.ndarray, positions: np.ndarray, grid: np.ndarray) -> dict:
    """Of the moves an agent makes off the target right after a move (not Stay), the share
    that undoes the previous one (its reverse) and that repeats it. ``actions`` (E, T, 2),
    -1 after an episode's end; ``positions`` (E, T + 1, 2, 2) before each step."""
    target = np.argwhere(grid == 2)[0]
    before = positions[:, 1:-1]  # where each later move starts
    counted = (actions[:, 1:] >= 0) & (actions[:, :-1] >= 0) & (actions[:, :-1] < 4)
    counted &= ~(before == target).all(axis=-1)
    previous = np.where(actions[:, :-1] >= 0, actions[:, :-1], 4)
    return {
        "undo": float((actions[:, 1:] == REVERSE[previous])[counted].mean()),
        "repeat": float((actions[:, 1:] == actions[:, :-1])[counted].mean()),
    }


def behaviour(models_dir: Path, grid: np.ndarray, max_steps: int, episodes: int) -> dict:
    """At ε = 0.05, over seeds: the share of an off-target agent's moves that undo its
    previous move and that repeat it; failures; and seed 641's recorded episodes."""
    undo, repeat, failed, recorded = [], [], [], None
    for seed in SEEDS:
        env = VectorMultiAgentEnv(episodes, grid=grid, max_steps=max_steps)
        policy = pair_policy(load_pair(models_dir, seed), env, CONDITIONS["eps"])
        results = recorded_episodes(env, policy, episodes, seed=EVAL_SEED)
        shares = move_shares(
            results.trajectories["actions"], results.trajectories["positions"], grid
        )
        undo.append(shares["undo"])
        repeat.append(shares["repeat"])
        failed.append(float(1 - results.successes.mean()))
        recorded = results if recorded is None else recorded
    return {
        "undo_previous_move": seed_statistics(undo),
        "repeat_previous_move": seed_statistics(repeat),
        "failed_episodes": seed_statistics(failed),
    }, recorded


def channel_stand_ins(map_seed: int) -> dict:
    """The map panel's test-time replacements of the distance (distance mode) and the
    message (comm mode) on ``map_seed``: success change at ε = 0.05 per probe."""
    panel = json.loads((PANEL_DIR / "panel.json").read_text(encoding="utf-8"))
    modes = panel["maps"][str(map_seed)]["behaviour"]["modes"]
    found = {}
    for mode, channel in (("distance", "distance"), ("comm", "message")):
        probes = modes[mode]["interventions"][channel]["eps"]["delta_success"]
        found[channel] = {p: probes[p] for p in CHANNEL_PROBES if p in probes}
    return found


def measure_map(map_seed: int, episodes: int) -> tuple[dict, dict]:
    """The map's entry (success of every agent, interventions, behaviour, stand-ins) and the
    recorded episodes of seed 641, memoryless and with memory."""
    memory_dir = MEMORY_PANEL_DIR / f"map{map_seed}" / "agent_models"
    memoryless_dir = PANEL_DIR / f"map{map_seed}" / "agent_models"
    grid, max_steps = read_batch(memory_dir)
    args = (grid, max_steps, episodes)
    success = {"memory": success_rates(memory_dir, *args)}
    for part in ABLATIONS:
        models = ABLATIONS_DIR / part / f"map{map_seed}" / "agent_models"
        success[f"{part}_only"] = success_rates(models, *args)
    success["memoryless"] = success_rates(memoryless_dir, *args)
    memory_behaviour, memory_episodes = behaviour(memory_dir, *args)
    memoryless_behaviour, memoryless_episodes = behaviour(memoryless_dir, *args)
    deltas = intervention_deltas(memory_dir, *args, success["memory"])
    entry = {
        "map_seed": map_seed,
        "target": np.argwhere(grid == 2)[0].tolist(),
        "success": {k: {c: seed_statistics(v[c]) for c in CONDITIONS} for k, v in success.items()},
        "interventions_delta_success": {
            k: {c: seed_statistics(v[c]) for c in CONDITIONS} for k, v in deltas.items()
        },
        "behaviour_eps": {"memoryless": memoryless_behaviour, "memory": memory_behaviour},
        "memoryless_channel_stand_ins_eps": channel_stand_ins(map_seed),
    }
    return entry, {"grid": grid, "memoryless": memoryless_episodes, "memory": memory_episodes}


def shown_episodes(shown: dict) -> dict:
    """The first test episode of seed 641 that the memoryless pair fails and the memory pair
    completes (the same start cells and exploration draws): its index, the map, and each
    pair's cells (L + 1, 2, 2) and outcome, as the figure draws them."""
    memoryless, memory = shown["memoryless"], shown["memory"]
    picked = np.flatnonzero(~memoryless.successes & memory.successes)
    index = int(picked[0]) if len(picked) else 0
    pairs = {}
    for label, results in (("memoryless", memoryless), ("memory", memory)):
        trace = episode_trace(results, index)
        pairs[label] = {"cells": trace.positions.tolist(), "success": trace.success}
    return {"index": index, "grid": shown["grid"].tolist(), "episodes": pairs}


def plot_episodes(path: Path, episodes: dict) -> None:
    """The two pairs of :func:`shown_episodes` side by side on the map."""
    fig = Figure(figsize=(6.5, 3.3), layout="constrained")
    labels = {"memoryless": "no memory", "memory": "one step of memory"}
    for ax, (key, label) in zip(fig.subplots(1, 2), labels.items(), strict=True):
        shown = episodes["episodes"][key]
        cells = np.asarray(shown["cells"])
        trace = EpisodeTrace(cells, np.zeros((len(cells) - 1, 2)), shown["success"])
        draw_map(ax, np.asarray(episodes["grid"]), star_size=12)
        draw_paths(ax, trace, marker_scale=0.8)
        grid = np.asarray(episodes["grid"])
        target_row, target_col = np.argwhere(grid == TARGET)[0]
        ax.plot(  # the target again, above the end markers that stand on it
            target_col, target_row, marker="*", ms=9, color="gold", mec="black", zorder=5
        )
        outcome = "meets" if trace.success else "fails"
        ax.set_title(f"{label}: {outcome} in {trace.length} steps", fontsize=FONT + 1)
        ax.tick_params(labelsize=FONT)
        ax.xaxis.label.set_size(FONT)
        ax.yaxis.label.set_size(FONT)
    handles, labels = fig.axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=4, fontsize=FONT, frameon=False)
    save_figure(fig, path, dpi=200)


def summarise(entries: list[dict], episodes: int, shown: dict) -> dict:
    return {
        "protocol": {
            "maps": list(MAPS),
            "mode": MODE,
            "training_seeds": list(SEEDS),
            "episodes_per_seed": episodes,
            "conditions": CONDITIONS,
            "evaluation_seed": EVAL_SEED,
            "success": "memory: the memory panel's agents (previous observation and move); "
            "move_only / observation_only: trained with one memory input zeroed; memoryless: "
            "the map panel's agents",
            "interventions": "success with the memory input replaced minus success with the "
            "real one, same episodes and draws, per seed: move_random (a uniform move), "
            "move_other_episode / observation_other_episode (the next copy's, another episode "
            "at the same step), zeros (the previous observation as at an episode start)",
            "behaviour": "at eps 0.05, moves of an agent off the target after a move: the "
            "share that undoes the previous move (the reverse direction) and that repeats it",
            "stand_ins": "the map panel's replacements of each channel (delta success at eps "
            "0.05): another episode's value at the same step, at a random step, the episode's "
            "own values shuffled in time, the run's mean",
            "figure": f"map {MAPS[0]}, seed {SEEDS[0]}, test episode {shown['index']}",
        },
        "maps": {str(e["map_seed"]): e for e in entries},
        "shown_episodes": shown,
    }


def parse_args(
    argv: list[str] | None,
    description: str = __doc__.split("\n\n")[0],
    train_help: str = "train the ablations' batches first",
) -> argparse.Namespace:
    """``--train``, ``--num_episodes`` and ``--workers``, checked (also the clock control's)."""
    parser = argparse.ArgumentParser(allow_abbrev=False, description=description)
    add = parser.add_argument
    add("--train", action="store_true", help=train_help)
    add("--num_episodes", type=int, default=1000, help="test episodes per seed (1..5000)")
    add("--workers", type=int, default=min(2, available_cores()), help="processes (1..64)")
    args = parser.parse_args(argv)
    if not 1 <= args.num_episodes <= 5000:
        parser.error(f"--num_episodes must be in 1..5000, got {args.num_episodes}")
    if not 1 <= args.workers <= 64:
        parser.error(f"--workers must be in 1..64, got {args.workers}")
    return args


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    args = parse_args(argv)
    if args.train:
        train_batches(ABLATIONS, MODE, ABLATIONS_DIR, args.workers)
    torch.set_num_threads(1)
    entries, shown = [], None
    for map_seed in MAPS:
        entry, episodes = measure_map(map_seed, args.num_episodes)
        entries.append(entry)
        shown = episodes if shown is None else shown
        print(
            f"map {map_seed}: "
            + ", ".join(f"{k} {v['eps']['mean']:.3f}" for k, v in entry["success"].items())
        )
    WHY_DIR.mkdir(parents=True, exist_ok=True)
    results = summarise(entries, args.num_episodes, shown_episodes(shown))
    plot_episodes(WHY_DIR / "why.png", results["shown_episodes"])
    write_json_atomic(WHY_DIR / "why.json", results)
    print(f"wrote {WHY_DIR}")
    return results


if __name__ == "__main__":
    run_command(main)
