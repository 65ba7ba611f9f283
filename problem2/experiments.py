"""Run a batch of training runs (modes x seeds) in parallel and write their outputs.

Used by ``python train.py``. For ``output_dir`` (default ``results``) it writes:

* ``agent_models/<mode>_seed<seed>_agent_{A,B}.pt``: TorchScript, mask included;
  ``agent_models/<mode>_agent_{A,B}.pt``: the best seed of each mode (by the final
  evaluation at ε = 0.05); ``agent_models/map.json``; ``agent_models/hyperparameters.json``.
* ``training_logs/<mode>_seed<seed>.csv``: one row per periodic evaluation;
  ``training_logs/<mode>_seed<seed>_final.json``: the final evaluation;
  ``training_logs/training_curves.png``; ``training_logs/timing.json`` (wall times,
  the only output that differs between identical reruns).
"""

from __future__ import annotations

import csv
import multiprocessing as mp
import queue
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from _atomic import temporary_path_for, write_json_atomic
from matplotlib.figure import Figure
from multi_agent_env import MultiAgentEnv, generate_map, save_map
from rollout import EVAL_EPSILON, EVAL_SEED, run_episodes, summarize
from train_config import TrainConfig
from trainer import MultiAgentTrainer

PROBLEM2 = Path(__file__).resolve().parent
MODE_COLOURS = {"independent": "#1b9e77", "comm": "#d95f02", "full": "#7570b3"}


def output_paths(cfg: TrainConfig) -> tuple[Path, Path]:
    """(agent_models/, training_logs/) under ``cfg.output_dir`` (relative to problem2/)."""
    root = Path(cfg.output_dir)
    root = root if root.is_absolute() else PROBLEM2 / root
    return root / "agent_models", root / "training_logs"


def run_name(mode: str, seed: int) -> str:
    return f"{mode}_seed{seed}"


def read_csv(path: Path) -> list[dict[str, float]]:
    with open(path, newline="") as handle:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]


def train_one(cfg: TrainConfig, mode: str, seed: int, progress_queue: Any = None) -> dict:
    """Train one (mode, seed), save its models, log and final evaluation; return the latter."""
    torch.set_num_threads(1)
    run_cfg = TrainConfig(**{**cfg.to_dict(), "mode": mode, "seed": seed, "seeds": []})
    env = MultiAgentEnv(
        grid_size=(cfg.grid_size, cfg.grid_size),
        max_steps=cfg.max_steps,
        seed=cfg.map_seed,
        reward_mode=cfg.reward_mode,
    )
    trainer = MultiAgentTrainer(env, run_cfg)
    name = run_name(mode, seed)
    models_dir, logs_dir = output_paths(cfg)
    trainer.models_dir, trainer.logs_dir = models_dir, logs_dir
    start = time.perf_counter()

    def report(row: dict[str, Any]) -> None:
        if progress_queue is not None:
            progress_queue.put((name, row, time.perf_counter() - start))
        if cfg.save_freq and row["env_steps"] % cfg.save_freq < cfg.eval_interval:
            trainer.save_models()

    trainer.train(report)  # writes the models and the log
    final: dict[str, Any] = {"mode": mode, "seed": seed}
    for label, epsilon in (("greedy", 0.0), ("eps", EVAL_EPSILON)):
        eval_env = trainer.make_vector_env(500, None)
        episodes = run_episodes(
            eval_env, trainer.policy(epsilon), cfg.final_eval_episodes, seed=EVAL_SEED, record=True
        )
        final[label] = {
            "epsilon": epsilon,
            **episode_statistics(episodes, eval_env.target_position),
        }
    write_json_atomic(logs_dir / f"{name}_final.json", final)
    final["seconds"] = time.perf_counter() - start
    return final


def episode_statistics(episodes: Any, target: tuple[int, int]) -> dict[str, Any]:
    """Success, steps and return of recorded episodes, plus the parking statistics: the share
    of steps with exactly one agent on the target, and the share of episodes in which one
    agent reached the target and the other never did."""
    summary = summarize(episodes)
    positions = episodes.trajectories["positions"][:, 1:]  # (E, T, 2, 2) after each step
    on_target = np.all(positions == np.array(target), axis=-1)  # (E, T, 2)
    in_episode = np.arange(positions.shape[1])[None, :] < episodes.lengths[:, None]  # (E, T)
    exactly_one = (on_target.sum(axis=-1) == 1) & in_episode
    reached = (on_target & in_episode[..., None]).any(axis=1)  # (E, 2)
    summary["share_steps_one_on_target"] = float(exactly_one.sum() / in_episode.sum())
    summary["share_episodes_one_never_arrives"] = float(np.mean(reached.sum(axis=1) == 1))
    return summary


def run_experiments(cfg: TrainConfig) -> list[dict[str, Any]]:
    """Train every (mode, seed) of ``cfg`` in ``cfg.workers`` processes and write all outputs."""
    models_dir, logs_dir = output_paths(cfg)
    models_dir.mkdir(parents=True, exist_ok=True)
    logs_dir.mkdir(parents=True, exist_ok=True)
    save_map(models_dir / "map.json", generate_map((cfg.grid_size, cfg.grid_size), cfg.map_seed))
    write_json_atomic(models_dir / "hyperparameters.json", cfg.to_dict())
    jobs = [(mode, seed) for mode in cfg.run_modes() for seed in cfg.run_seeds()]
    finals = _run_parallel(cfg, jobs)

    write_json_atomic(
        logs_dir / "timing.json",
        {run_name(f["mode"], f["seed"]): round(f.pop("seconds"), 1) for f in finals},
    )
    for mode in cfg.run_modes():
        runs = [f for f in finals if f["mode"] == mode]
        best = max(
            runs, key=lambda f: (f["eps"]["success_rate"], f["greedy"]["success_rate"], -f["seed"])
        )
        for agent in "AB":
            source = models_dir / f"{run_name(mode, best['seed'])}_agent_{agent}.pt"
            with temporary_path_for(models_dir / f"{mode}_agent_{agent}.pt") as temporary:
                shutil.copyfile(source, temporary)
    title = (
        f"Training progress on map seed {cfg.map_seed}"
        + (f" (reward {cfg.reward_mode})" if cfg.reward_mode != "arrival" else "")
        + (", untrained messages" if cfg.comm_learning == "none" else "")
    )
    plot_training_curves(logs_dir, cfg.run_modes(), cfg.run_seeds(), title)
    return finals


def _run_parallel(cfg: TrainConfig, jobs: list[tuple[str, int]]) -> list[dict[str, Any]]:
    """Run ``jobs`` in a process pool, printing one progress line for the whole batch."""
    progress = ProgressLine(len(jobs), cfg.total_steps)
    if cfg.workers <= 1 or len(jobs) == 1:
        finals = []
        for mode, seed in jobs:
            finals.append(train_one(cfg, mode, seed, progress))
            progress.runs_done += 1
        progress.close()
        return finals
    context = mp.get_context("spawn")  # fresh interpreters: no inherited torch thread state
    with context.Manager() as manager, context.Pool(min(cfg.workers, len(jobs))) as pool:
        progress_queue = manager.Queue()
        pending = [
            pool.apply_async(train_one, (cfg, mode, seed, progress_queue)) for mode, seed in jobs
        ]
        while not all(p.ready() for p in pending):
            progress.runs_done = sum(p.ready() for p in pending)
            try:
                progress.put(progress_queue.get(timeout=1.0))
            except queue.Empty:
                progress.show()
        finals = [p.get() for p in pending]
    progress.close()
    return finals


class ProgressLine:
    """One terminal line for a batch of runs: runs finished, env steps, speed, ETA and the
    latest evaluation. ``put`` takes the ``(run name, log row, seconds)`` the runs report."""

    def __init__(self, n_runs: int, steps_per_run: int) -> None:
        self.n_runs, self.steps_per_run, self.runs_done = n_runs, steps_per_run, 0
        self.start = time.perf_counter()
        self.rows: dict[str, dict[str, Any]] = {}
        self.latest = ""

    def put(self, item: tuple[str, dict[str, Any], float]) -> None:
        self.latest, row, _ = item
        self.rows[self.latest] = row
        self.show()

    def show(self) -> None:
        total = self.n_runs * self.steps_per_run
        done = sum(min(row["env_steps"], self.steps_per_run) for row in self.rows.values())
        elapsed = time.perf_counter() - self.start
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = f"{(total - done) / rate / 60:4.1f} min" if rate > 0 else "  ?"
        line = (
            f"\r[{self.runs_done}/{self.n_runs} runs] {done:,}/{total:,} env steps  "
            f"{rate:,.0f} steps/s  ETA {eta}"
        )
        if self.latest:
            row = self.rows[self.latest]
            line += (
                f" | {self.latest} ε {row['epsilon']:.2f}  success ε=0.05 "
                f"{row['eval_success_eps']:.2f} greedy {row['eval_success_greedy']:.2f}"
            )
        print(line.ljust(150), end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        self.show()
        print(file=sys.stderr)


def plot_training_curves(logs_dir: Path, modes: list[str], seeds: list[int], title: str) -> Path:
    """Evaluation return and success rate against env steps, mean over seeds, min–max band."""
    fig = Figure(figsize=(12, 4.4), layout="constrained")
    axes = fig.subplots(1, 2)
    panels = (("eval_return_eps", "average episode reward"), ("eval_success_eps", "success rate"))
    for mode in modes:
        logs = [read_csv(logs_dir / f"{run_name(mode, seed)}.csv") for seed in seeds]
        steps = np.array([row["env_steps"] for row in logs[0]])
        for ax, (key, _) in zip(axes, panels, strict=True):
            values = np.array([[row[key] for row in log] for log in logs])
            ax.plot(steps, values.mean(axis=0), color=MODE_COLOURS.get(mode), label=mode)
            ax.fill_between(
                steps,
                values.min(axis=0),
                values.max(axis=0),
                color=MODE_COLOURS.get(mode),
                alpha=0.2,
            )
    for ax, (_, label) in zip(axes, panels, strict=True):
        ax.set_xlabel("environment steps")
        ax.set_ylabel(f"{label} (evaluation, ε = 0.05)")
        ax.grid(True, alpha=0.3)
    axes[1].set_ylim(0, 1)
    axes[0].legend(title=f"mode (mean of {len(seeds)} seeds, band min–max)")
    fig.suptitle(title)
    path = logs_dir / "training_curves.png"
    with temporary_path_for(path) as temporary:
        fig.savefig(temporary, format="png", dpi=150)
    return path


__all__ = ["plot_training_curves", "run_experiments", "train_one"]
