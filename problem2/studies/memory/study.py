"""Memory study: what the message, the distance and memory buy on maps that cannot be
memorised.

GRU agents (``agents.py``, trained by ``learner.py``) of the four modes of the channels'
2 x 2 (independent, comm, distance, full) learn on the map pool of the map-pool study, with
its recipe (``map_pool_study.RECIPE``) but for the sizes of sequence replay (``RECIPE``
here), and are tested on the 40 held-out maps from their exported files (the memory
contract), greedy and at ε = 0.05, 500 episodes per map. On the same test episodes, per
run: the channel interventions (``analysis/interventions.py``: the message or the distance
replaced by another episode's value at the same step, by the run's mean, by 0 or 1), what
the message says (its mean on and off the target) and the homing share (while the partner
stands on the target, how often a move brings the agent closer to it, farther, or neither),
beside the beacon explorer's.

The memoryless agents are the map-pool study's (``map_pool/map_pool.json``, the same seeds
0–4): ``memory_minus_no_memory`` pairs each memory run with the memoryless run of its mode
and seed. Outputs in ``results/studies/memory`` (written into a staging folder and moved
into place whole): ``memory.json``, ``memory.png``, ``agent_models/``, ``training_logs/``,
``timing.json`` (wall times: the only file that differs between identical reruns).
``--plot_only`` redraws ``memory.png`` from ``memory.json`` without training.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.arrivals import homing_shares
from analysis.map_sets import HELD_OUT_MAP_SEEDS
from analysis.runs import load_policy
from analysis.stats import seed_paired_differences, seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from matplotlib.figure import Figure
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_SEED
from settings import SettingError, check_value, int_in, usage, validated

from studies import map_pool_study, pool_training
from studies.memory.agents import MEMORY_MODES
from studies.memory.held_out_tests import (
    CHANNELS,
    CONDITIONS,
    beacon_homing,
    held_out_results,
)
from studies.memory.learner import TRANSITIONS_PER_EPISODE, RecurrentTrainer
from studies.pool_training import PoolConfig
from studies.staging import (
    best_env_steps,
    best_selection,
    check_field,
    run_command,
    staged_output,
    train_into,
    write_timing,
)

RESULTS = Path(__file__).resolve().parents[2] / "results" / "studies"
STUDY_DIR = RESULTS / "memory"
NO_MEMORY = RESULTS / "map_pool" / "map_pool.json"
# One update of 16 stored episodes (batch_size // 16) per vector step of 64 copies; runs
# of 400 k steps.
RECIPE: dict[str, Any] = map_pool_study.RECIPE | dict(
    total_steps=400_000, updates_per_step=1, batch_size=256
)
DIFFERENCES = (
    ("full", "independent"),
    ("full", "distance"),
    ("comm", "independent"),
    ("distance", "independent"),
)


def train_and_test(
    cfg: PoolConfig, mode: str, seed: int, staging: Path, episodes: int, progress: Any = None
) -> dict[str, Any]:
    """Train one (mode, seed) on the map pool into ``staging``, then test its exported pair."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    run_cfg = dataclasses.replace(cfg, seed=seed, seeds=[], workers=1)
    env = MultiAgentEnv(grid_size=cfg.grid_shape(), max_steps=cfg.max_steps, seed=cfg.map_seed)
    trainer = RecurrentTrainer(env, run_cfg, mode)
    train_into(trainer, staging, progress, start)
    trained = time.perf_counter() - start
    agents = tuple(load_policy(trainer.models_dir / f"{trainer.name}_agent_{a}.pt") for a in "AB")
    tested = held_out_results(agents, mode, episodes, cfg.max_steps)
    return {
        "mode": mode,
        "seed": seed,
        "selected_env_steps": best_env_steps(trainer),
        "validation_success": best_selection(trainer),
        **tested,
        "seconds": {"training": trained, "total": time.perf_counter() - start},
    }


def summarise(
    cfg: PoolConfig, runs: list[dict], beacon: list[float], no_memory: dict | None
) -> dict:
    """The study's JSON (everything but wall times)."""
    by_mode = {
        m: [r for r in runs if r["mode"] == m]
        for m in MEMORY_MODES
        if any(r["mode"] == m for r in runs)
    }
    modes: dict[str, Any] = {}
    for mode, mine in by_mode.items():
        entry: dict[str, Any] = {
            c: seed_statistics([r["success"][c] for r in mine]) for c in CONDITIONS
        }
        entry["seeds"] = [r["seed"] for r in mine]
        entry["interventions_delta_success"] = {
            name: {
                c: seed_statistics([r["interventions"][name][c] for r in mine]) for c in CONDITIONS
            }
            for name in mine[0]["interventions"]
        }
        homing = np.sum([r["homing_counts_eps"] for r in mine], 0).tolist()
        entry["homing_share_eps"], entry["homing_counts_eps"] = homing_shares(homing), homing
        if mode in CHANNELS["message"][1]:
            entry["cic_bits"] = {
                k: seed_statistics([r["cic_greedy_episodes"][k] for r in mine])
                for k in mine[0]["cic_greedy_episodes"]
            }
            sums = np.sum([r["message_on_off_eps"] for r in mine], 0)
            entry["mean_message_eps"] = {
                "on_target": sums[0] / max(sums[1], 1),
                "off_target": sums[2] / max(sums[3], 1),
            }
        modes[mode] = entry
    seeds_of = {m: {r["seed"]: r for r in mine} for m, mine in by_mode.items()}
    success = {(r["mode"], r["seed"]): r["success"] for r in runs}
    differences = seed_paired_differences(success, DIFFERENCES, CONDITIONS)
    memory_gain = {}
    if no_memory is not None:
        for mode, runs_of_mode in seeds_of.items():
            paired = {s: no_memory["runs"].get(f"{mode}_seed{s}") for s in runs_of_mode}
            common = sorted(s for s, r in paired.items() if r is not None)
            if common:
                memory_gain[mode] = {
                    c: seed_statistics(
                        [
                            runs_of_mode[s]["success"][c] - paired[s]["held_out_mean"][c]
                            for s in common
                        ]
                    )
                    for c in CONDITIONS
                } | {"seeds": common}
    return {
        "description": "GRU agents trained on a pool of generated maps, tested on held-out maps",
        "protocol": {
            "held_out_map_seeds": list(HELD_OUT_MAP_SEEDS),
            "conditions": CONDITIONS,
            "start_cells_seed": EVAL_SEED,
            "policy_seed": f"{EVAL_SEED} + map seed",
            "episodes_per_batch": max(1, cfg.batch_size // TRANSITIONS_PER_EPISODE),
            "homing": "moves made at eps 0.05 while the partner is on the target and "
            "the agent is not; Manhattan distance to the target",
            "interventions": "success with the channel replaced minus success with the "
            "real channel, same episodes; constant_mean is the run's own mean on the map",
            "cic": "causal influence of the partner's message on the receiver's policy at "
            "eps 0.05 (analysis.information), on the greedy episodes, the receiver's previous "
            "action and hidden state held at the recorded ones; mean over maps and directions",
        },
        "recipe": cfg.hyperparameters(),
        "departures_from_the_assignment": map_pool_study.DEPARTURES
        | {"memory": "a GRU between the hidden layer and the heads; the previous action as input"},
        "held_out": {
            "modes": modes,
            "differences": differences,
            "memory_minus_no_memory": memory_gain,
            "beacon_explorer_homing_share_greedy": homing_shares(beacon),
        },
        "runs": {
            f"{r['mode']}_seed{r['seed']}": {k: v for k, v in r.items() if k != "seconds"}
            for r in runs
        },
    }


def plot(path: Path, results: dict, no_memory: dict | None) -> None:
    """Held-out success at ε = 0.05 per mode, without memory (the map-pool study) and with
    (bars: mean over seeds, whiskers: 95 % CI, dots: seeds), beside the explorers."""
    fig = Figure(figsize=(map_pool_study.FIGURE_WIDTH, 3.2), layout="constrained")
    ax = fig.subplots()
    modes = list(results["held_out"]["modes"])
    earlier = no_memory["held_out"]["modes"] if no_memory else {}
    arms = [
        ("no memory (map-pool study)", "#9aa9c2", {m: earlier[m]["eps"] for m in earlier}),
        ("GRU memory", "#4c72b0", {m: s["eps"] for m, s in results["held_out"]["modes"].items()}),
    ]
    map_pool_study.draw_success_bars(ax, modes, arms)
    ax.set_xticks(range(len(modes)), [m if m in earlier else f"{m}\n(memory only)" for m in modes])
    if no_memory:
        map_pool_study.draw_reference_lines(ax, no_memory["held_out"]["heuristics"])
    label = f"success on {len(HELD_OUT_MAP_SEEDS)} held-out maps (ε = {CONDITIONS['eps']:g})"
    map_pool_study.save_bars(fig, ax, label, path)


def read_no_memory() -> dict | None:
    return json.loads(NO_MEMORY.read_text(encoding="utf-8")) if NO_MEMORY.is_file() else None


def run_study(
    cfg: PoolConfig, modes: list[str], seeds: list[int], episodes: int, output_dir: Path
) -> dict:
    """Train and test every (mode, seed) in ``cfg.workers`` processes; install the outputs
    in ``output_dir`` whole (or not at all)."""
    with staged_output(output_dir) as staging:
        jobs = [(cfg, mode, seed, staging, episodes) for mode in modes for seed in seeds]
        runs = run_jobs(train_and_test, jobs, cfg.workers, ProgressLine(len(jobs), cfg.total_steps))
        no_memory = read_no_memory()
        results = summarise(cfg, runs, beacon_homing(episodes, cfg.max_steps), no_memory)
        write_json_atomic(staging / "memory.json", results)
        plot(staging / "memory.png", results, no_memory)
        write_timing(staging / "timing.json", runs)
    return results


def resummarise(cfg: PoolConfig, episodes: int, output_dir: Path) -> dict:
    """The study's summary from the runs its memory.json records (what ``run_study`` feeds
    ``summarise``, less the wall times) and the current map-pool results: what a rerun
    writes when training gives the same runs, without the 30 minutes of training."""
    recorded = json.loads((output_dir / "memory.json").read_text(encoding="utf-8"))
    runs = list(recorded["runs"].values())
    no_memory = read_no_memory()
    results = summarise(cfg, runs, beacon_homing(episodes, cfg.max_steps), no_memory)
    write_json_atomic(output_dir / "memory.json", results)
    plot(output_dir / "memory.png", results, no_memory)
    return results


def format_table(results: dict) -> str:
    lines = map_pool_study.held_out_lines(results, 14)
    for name, entry in results["held_out"]["differences"].items():
        s = entry["eps"]
        lines.append(f"{name:<22} eps {s['mean']:+.3f} [{s['ci95'][0]:+.3f}, {s['ci95'][1]:+.3f}]")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> tuple[PoolConfig, argparse.Namespace]:
    parser = pool_training.study_parser(
        __doc__.split("\n\n")[0], RECIPE, MEMORY_MODES, STUDY_DIR, "memory"
    )
    add = parser.add_argument
    add(
        "--summarise_only",
        "--summarise-only",
        action="store_true",
        help="rewrite memory.json and memory.png from the runs memory.json records (their "
        "test results) and the current map-pool results (no training)",
    )
    args = parser.parse_args(argv)
    for flag in ("plot_only", "summarise_only"):
        if getattr(args, flag) and not (args.output_dir / "memory.json").is_file():
            parser.error(f"--{flag}: {args.output_dir / 'memory.json'} does not exist")
    modes = list(MEMORY_MODES) if args.mode == "all" else args.mode.split(",")
    unknown = [m for m in modes if m not in MEMORY_MODES]
    if unknown:
        parser.error(
            f"--mode: unknown {', '.join(unknown)}; use all or some of {', '.join(MEMORY_MODES)}"
        )
    settings = RECIPE | {"total_steps": args.total_steps, "seeds": [], "workers": args.workers}
    try:
        check_value("episodes_per_map", args.episodes_per_map, int_in(1, 100_000))
        check_field("num_seeds", args.num_seeds)
        check_field("output_dir", str(args.output_dir))
        cfg = validated(PoolConfig(**settings))
    except SettingError as error:
        parser.error(usage(error))
    args.modes, args.seeds = modes, list(range(args.num_seeds))
    return cfg, args


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    cfg, args = parse_args(argv)
    if args.plot_only:
        results = json.loads((args.output_dir / "memory.json").read_text(encoding="utf-8"))
        plot(args.output_dir / "memory.png", results, read_no_memory())
        print(f"wrote {args.output_dir / 'memory.png'}")
        return results
    start = time.perf_counter()
    if args.summarise_only:
        results = resummarise(cfg, args.episodes_per_map, args.output_dir)
    else:
        results = run_study(cfg, args.modes, args.seeds, args.episodes_per_map, args.output_dir)
    print(format_table(results))
    print(f"wrote {args.output_dir} ({time.perf_counter() - start:.0f} s)")
    return results


if __name__ == "__main__":
    run_command(main)
