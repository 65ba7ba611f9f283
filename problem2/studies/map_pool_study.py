"""Maps that cannot be memorised: train on a pool of generated maps, test on held-out ones.

    python map_pool_study.py                    # 3 modes x 5 seeds, writes the study folder
    python map_pool_study.py --total_steps 300000 --num_seeds 2 --output_dir /tmp/pool
    python map_pool_study.py --plot_only         # redraw map_pool.png from map_pool.json

Every run trains through the core loop (``studies.pool_training.PoolTrainer``) on
``map_pool`` training maps (a new one drawn at every episode start, ``analysis.map_sets``),
keeps the checkpoint that scored best on the validation maps, and is then tested on the 40
held-out maps (``HELD_OUT_MAP_SEEDS``), greedy and at epsilon = 0.05, ``--episodes_per_map``
episodes each, through :func:`analysis.held_out.held_out_success`. The memoryless and
sweeping explorers, the random policy and the shortest-path oracle of :mod:`baselines` are
tested the same way.

The recipe (``RECIPE``) departs from the assignment's setting in two named ways:
parameter sharing (one set of weights for both agents instead of independent learners)
and reward shaping for learning (a bonus per newly seen cell and per agent on the
target); the network is the assignment's (one hidden layer of 64 units) and the reported
successes are the task's own (both agents on the target within 50 steps).

Outputs in ``--output_dir`` (default ``results/studies/map_pool``), written into a
staging folder and moved into place whole: ``map_pool.json`` (``held_out``: per mode the
mean success over seeds with a 95 % bootstrap CI and the per-seed values, and the
heuristics with a CI over maps; ``runs``: per run the selected checkpoint, its
validation score and its success per held-out map), ``map_pool.csv``, ``map_pool.png``,
``agent_models/`` (TorchScript pairs, mask inside, equal weights for A and B),
``training_logs/`` (one CSV per run) and ``timing.json`` (wall times: the only file that
differs between identical reruns).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

from safety import make_console_safe, temporary_path_for, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.baselines import POLICY_LABELS
from analysis.held_out import baselines_on_held_out, held_out_success
from analysis.map_sets import (
    HELD_OUT_MAP_SEEDS,
    MAX_POOL_SIZE,
    TRAINING_FIRST_SEED,
    VALIDATION_FIRST_SEED,
)
from analysis.stats import BOOTSTRAP_RESAMPLES, seed_paired_differences, seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_EPSILON, EVAL_SEED, VALIDATION_SEED
from settings import MODES, SettingError, check_value, int_in, usage, validated

from studies import pool_training
from studies.pool_training import PoolConfig, PoolTrainer
from studies.staging import (
    best_env_steps,
    best_selection,
    check_field,
    run_command,
    staged_output,
    train_into,
    write_timing,
)

STUDY_DIR = Path(__file__).resolve().parent.parent / "results" / "studies" / "map_pool"
RECIPE: dict[str, Any] = dict(
    map_pool=2000,
    validation_maps=200,
    share_weights=True,
    coverage_bonus=0.05,
    on_target_bonus=0.1,
    n_step=3,
    gamma=0.95,
    lr=2.5e-4,
    target_update=1000,
    batch_size=256,
    updates_per_step=2,
    hidden_dim=64,
    total_steps=1_000_000,
    select_by="success",
    epsilon_fraction=0.3,
    lr_end_factor=0.1,
    eval_interval=50_000,
    eval_episodes=500,
    seeds=[0, 1, 2, 3, 4],
    reward_mode="arrival",
    target_potential=0.0,
    advantage_learning=0.0,
)
# The recipe keeps its own reward and TD target (the arrival reward, no advantage learning):
# the main experiment's defaults changed after the recipe was chosen.
STUDY_POOL_SIZES = int_in(1, MAX_POOL_SIZE)  # a pool of maps: train.py's 0 (one map) is not one
CONDITIONS = {"greedy": 0.0, "eps": EVAL_EPSILON}
FIGURE_WIDTH = 4.3  # inches: report/map_pool.typ and memory.typ print the figures this wide
FONT = 8  # points, the smallest text of the figures
HEURISTICS = ("explorer", "sweep_explorer", "beacon_explorer", "random", "oracle")
MODE_DIFFERENCES = (("comm", "independent"), ("full", "comm"), ("full", "independent"))
DEPARTURES = {
    "share_weights": "parameter sharing: both agents act with one set of weights (summed "
    "gradient) instead of two independent learners",
    "coverage_bonus": "reward shaping for learning only: a bonus per grid cell seen for the "
    "first time in the episode by either agent",
    "on_target_bonus": "reward shaping for learning only: a bonus per agent on the target",
}


def train_and_test(
    cfg: PoolConfig, mode: str, seed: int, staging: Path, episodes: int, progress: Any = None
) -> dict[str, Any]:
    """Train one (mode, seed) on the map pool into ``staging``, then test it on the
    held-out maps; returns the run's record."""
    torch.set_num_threads(1)
    start = time.perf_counter()
    run_cfg = dataclasses.replace(cfg, mode=mode, seed=seed, seeds=[], workers=1)
    # With a map pool only the grid size, window and time limit of this env are used.
    env = MultiAgentEnv(grid_size=cfg.grid_shape(), max_steps=cfg.max_steps, seed=cfg.map_seed)
    trainer = PoolTrainer(env, run_cfg)
    train_into(trainer, staging, progress, start)
    trained = time.perf_counter() - start
    rates = held_out_success(
        lambda grid, map_seed, epsilon: trainer.policy(epsilon, seed=EVAL_SEED + map_seed),
        episodes,
        cfg.max_steps,
        CONDITIONS,
    )
    return {
        "mode": mode,
        "seed": seed,
        "selected_env_steps": best_env_steps(trainer),
        "validation_success": {k: best_selection(trainer)[k] for k in CONDITIONS},
        "held_out_per_map": rates,
        "held_out_mean": {label: float(np.mean(values)) for label, values in rates.items()},
        "seconds": {"training": trained, "total": time.perf_counter() - start},
    }


def heuristic_results(episodes: int, max_steps: int) -> dict[str, Any]:
    """The baseline policies on the held-out maps, seed statistics over maps."""
    per_map = baselines_on_held_out(HEURISTICS, episodes, max_steps)
    return {name: seed_statistics(rates) | {"per_map": rates} for name, rates in per_map.items()}


def summarise(cfg: PoolConfig, runs: list[dict], heuristics: dict, episodes: int) -> dict:
    """The study's JSON (everything but wall times)."""
    modes: dict[str, Any] = {}
    for mode in cfg.run_modes():
        mine = [r for r in runs if r["mode"] == mode]
        modes[mode] = {
            label: seed_statistics([r["held_out_mean"][label] for r in mine])
            for label in CONDITIONS
        } | {"seeds": [r["seed"] for r in mine]}
    success = {(r["mode"], r["seed"]): r["held_out_mean"] for r in runs}
    differences = seed_paired_differences(success, MODE_DIFFERENCES, CONDITIONS)
    return {
        "description": "agents trained on a pool of generated maps, tested on held-out maps",
        "protocol": {
            "held_out_map_seeds": list(HELD_OUT_MAP_SEEDS),
            "episodes_per_map": episodes,
            "start_cells_seed": EVAL_SEED,
            "policy_seed": f"{EVAL_SEED} + map seed",
            "conditions": CONDITIONS,
            "training_map_seeds": f"from {TRAINING_FIRST_SEED}, {cfg.map_pool} maps",
            "validation_map_seeds": f"from {VALIDATION_FIRST_SEED}, {cfg.validation_maps} maps",
            "validation_start_cells_seed": VALIDATION_SEED,
            "checkpoint_selection": "best mean of greedy and epsilon 0.05 success on the "
            f"validation maps, every {cfg.eval_interval} env steps",
            "excluded_from_pools": "the held-out maps and the default map (seed 641)",
            "confidence": 0.95,
            "bootstrap_resamples": BOOTSTRAP_RESAMPLES,
            "success": "both agents on the target on the same step within max_steps",
        },
        "recipe": cfg.hyperparameters(),
        "departures_from_the_assignment": DEPARTURES,
        "held_out": {
            "modes": modes,
            "differences": differences,
            "heuristics": heuristics,
            "note": "modes: ci95 and per_seed over training seeds (each the mean over the "
            "held-out maps); differences: the first mode's success minus the second's, per "
            "training seed, ci95 over seeds; heuristics: ci95 and per_seed over maps",
        },
        "runs": {
            f"{r['mode']}_seed{r['seed']}": {k: v for k, v in r.items() if k != "seconds"}
            for r in runs
        },
    }


def write_csv(path: Path, results: dict) -> None:
    """One row per run and per heuristic: held-out success greedy and at epsilon 0.05."""
    with (
        temporary_path_for(path) as temporary,
        open(temporary, "w", newline="", encoding="utf-8") as handle,
    ):
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(["policy", "seed", "held_out_success_greedy", "held_out_success_eps"])
        for run in results["runs"].values():
            means = run["held_out_mean"]
            writer.writerow([run["mode"], run["seed"], means["greedy"], means["eps"]])
        for name, stats in results["held_out"]["heuristics"].items():
            writer.writerow([name, "", stats["mean"], ""])


def draw_success_bars(ax: Axes, modes: list[str], arms: list[tuple[str, str, dict]]) -> None:
    """Held-out success per mode for each arm (label, colour, mode -> condition statistics
    with ``mean``, ``ci95``, ``per_seed``): bars at the mean, whiskers over the 95 % CI and a
    dot per seed. A mode an arm has no run of gets no slot; its other bars close up."""
    for i, mode in enumerate(modes):
        present = [arm for arm in arms if mode in arm[2]]
        for k, (label, colour, stats_of) in enumerate(present):
            x, stats = i + 0.36 * (k - (len(present) - 1) / 2), stats_of[mode]
            low, high = stats["ci95"]
            ax.bar(x, stats["mean"], 0.34, color=colour, label=label)
            ax.errorbar(
                x,
                stats["mean"],
                [[stats["mean"] - low], [high - stats["mean"]]],
                color="black",
                capsize=3,
            )
            ax.plot([x] * len(stats["per_seed"]), stats["per_seed"], "k.", ms=3)
    ax.set_xticks(range(len(modes)), modes)
    ax.set_ylim(0, 1)
    ax.grid(True, axis="y", alpha=0.3)


def draw_reference_lines(ax: Axes, heuristics: dict) -> None:
    """The explorers' held-out success as grey lines, each named with its value on the
    right-hand axis."""
    names = ("explorer", "sweep_explorer", "beacon_explorer")
    for name, style in zip(names, (":", "--", "-."), strict=True):
        ax.axhline(heuristics[name]["mean"], color="grey", ls=style, lw=1.2)
    right = ax.twinx()
    right.set_ylim(ax.get_ylim())
    means = [heuristics[name]["mean"] for name in names]
    right.set_yticks(
        means, [f"{POLICY_LABELS[n]}\n{m:.2f}" for n, m in zip(names, means, strict=True)]
    )
    right.tick_params(length=0, labelsize=FONT, labelcolor="0.35")


def save_bars(fig: Figure, ax: Axes, ylabel: str, path: Path) -> None:
    """The figure's one legend (an entry per arm) below it, the axis label, the file."""
    ax.set_ylabel(ylabel, fontsize=FONT + 1)
    ax.tick_params(labelsize=FONT)
    handles = dict(zip(*reversed(ax.get_legend_handles_labels()), strict=True))
    fig.legend(
        handles.values(),
        handles.keys(),
        loc="outside lower center",
        ncols=len(handles),
        fontsize=FONT + 1,
        frameon=False,
    )
    with temporary_path_for(path) as temporary:
        fig.savefig(temporary, format="png", dpi=200)


def plot(path: Path, results: dict) -> None:
    """Held-out success per mode (bars: mean over seeds, whiskers: 95 % CI, dots: seeds)
    beside the explorers (lines), at the width the report prints it."""
    fig = Figure(figsize=(FIGURE_WIDTH, 3.2), layout="constrained")
    ax = fig.subplots()
    modes = results["held_out"]["modes"]
    arms = [
        (
            f"{'greedy' if c == 'greedy' else 'ε-greedy'} (ε = {CONDITIONS[c]:g})",
            colour,
            {m: modes[m][c] for m in modes},
        )
        for c, colour in (("greedy", "#4c72b0"), ("eps", "#dd8452"))
    ]
    draw_success_bars(ax, list(modes), arms)
    draw_reference_lines(ax, results["held_out"]["heuristics"])
    save_bars(fig, ax, f"success on {len(HELD_OUT_MAP_SEEDS)} held-out maps", path)


def run_study(cfg: PoolConfig, episodes: int, output_dir: Path) -> dict:
    """Train and test every (mode, seed) of ``cfg`` in ``cfg.workers`` processes, test the
    heuristics, and install the outputs in ``output_dir`` whole (or not at all)."""
    with staged_output(output_dir) as staging:
        jobs = [(mode, seed) for mode in cfg.run_modes() for seed in cfg.run_seeds()]
        progress = ProgressLine(len(jobs), cfg.total_steps)
        arguments = [(cfg, mode, seed, staging, episodes) for mode, seed in jobs]
        runs = run_jobs(train_and_test, arguments, cfg.workers, progress)
        heuristics = heuristic_results(episodes, cfg.max_steps)
        results = summarise(cfg, runs, heuristics, episodes)
        write_json_atomic(staging / "map_pool.json", results)
        write_csv(staging / "map_pool.csv", results)
        plot(staging / "map_pool.png", results)
        write_timing(staging / "timing.json", runs)
    return results


def held_out_lines(results: dict, width: int) -> list[str]:
    """A header and a line per mode (names padded to ``width``): held-out success, greedy and
    at epsilon 0.05, with 95 % CIs."""
    lines = [f"{'held-out success':<{width}} {'greedy (95% CI)':>22} {'eps 0.05 (95% CI)':>22}"]
    for mode, entry in results["held_out"]["modes"].items():
        cells = [
            f"{s['mean']:.3f} [{s['ci95'][0]:.3f}, {s['ci95'][1]:.3f}]"
            for s in (entry["greedy"], entry["eps"])
        ]
        lines.append(f"{mode:<{width}} {cells[0]:>22} {cells[1]:>22}")
    return lines


def format_table(results: dict) -> str:
    lines = held_out_lines(results, 16)
    for name, stats in results["held_out"]["heuristics"].items():
        lines.append(f"{name:<16} {stats['mean']:>9.3f} (CI over maps)")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The study's command-line flags."""
    description = __doc__.split("\n\n")[0]
    return pool_training.study_parser(
        description, RECIPE, MODES, STUDY_DIR, "map_pool", with_map_pool=True
    )


def parse_args(argv: list[str] | None) -> tuple[PoolConfig, argparse.Namespace]:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.plot_only and not (args.output_dir / "map_pool.json").is_file():
        parser.error(f"--plot_only: {args.output_dir / 'map_pool.json'} does not exist")
    settings = RECIPE | {
        "total_steps": args.total_steps,
        "seeds": list(range(args.num_seeds)),
        "mode": args.mode,
        "map_pool": args.map_pool,
        "workers": args.workers,
    }
    try:
        check_value("episodes_per_map", args.episodes_per_map, int_in(1, 100_000))
        check_value("map_pool", args.map_pool, STUDY_POOL_SIZES)
        # Flags turned into other fields are checked by their field's rule alone.
        check_field("num_seeds", args.num_seeds)  # the seeds 0..num_seeds-1
        check_field("output_dir", str(args.output_dir))  # the study's own folder
        cfg = validated(PoolConfig(**settings))
    except SettingError as error:
        parser.error(usage(error))
    return cfg, args


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    cfg, args = parse_args(argv)
    if args.plot_only:
        results = json.loads((args.output_dir / "map_pool.json").read_text(encoding="utf-8"))
        plot(args.output_dir / "map_pool.png", results)
        print(f"wrote {args.output_dir / 'map_pool.png'}")
        return results
    start = time.perf_counter()
    results = run_study(cfg, args.episodes_per_map, args.output_dir)
    print(format_table(results))
    print(f"wrote {args.output_dir} ({time.perf_counter() - start:.0f} s)")
    return results


if __name__ == "__main__":
    run_command(main)
