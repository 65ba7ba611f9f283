"""Train the two agents of Problem 2: each ablation mode x several seeds, on one map.

    python train.py                      # 3 modes x 10 seeds on the default map (seed 641)
    python train.py --mode full --seeds 641 642 --total_steps 200000 --output_dir my_run
    python train.py --help               # every setting, its meaning and its allowed range

Read from :func:`main` down: the flags (``settings.TrainConfig``: each setting's default,
meaning and check, declared once), the output folder's checks (``output_folder.py``), then
for each mode and seed :func:`train_one`: the environment, the learner
(``trainer.DQNTrainer``), ``train()``, the saved models and log, and the validation that
picks each mode's best seed (:func:`best_runs`); then the curves and the batch's record
(``output_folder.record_batch``). :func:`apply_observation_mask` and
:class:`MultiAgentTrainer` are the course skeleton's names.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import multiprocessing
import sys
import time
from pathlib import Path
from typing import Any

import safety  # first: checks the packages (standard library only)

import numpy as np
import output_folder
import torch
from models import observation_mask
from rollout import EVAL_EPSILON, EVAL_SEED, VALIDATION_SEED, select_best
from settings import (
    DEFAULT_OUTPUT_DIR,
    SettingError,
    TrainConfig,
    build_parser,
    parse_config,
    usage,
    validated,
)
from trainer import DQNTrainer
from vector_env import NUM_ACTIONS, VectorMultiAgentEnv, generate_map

__all__ = ["EVAL_EPSILON", "MultiAgentTrainer", "TrainConfig", "apply_observation_mask", "main"]

MODE_COLOURS = {
    "independent": "#1b9e77",
    "comm": "#d95f02",
    "distance": "#e7298a",
    "full": "#7570b3",
}


def apply_observation_mask(obs: np.ndarray | torch.Tensor, mode: str) -> np.ndarray | torch.Tensor:
    """Zero the inputs that ablation ``mode`` hides (``models.MASKED_INPUTS``): ``independent``
    the message and the distance (elements 9 and 10 for a 3 x 3 window), ``comm`` the
    distance, ``distance`` the message, ``full`` none. Any leading shape (..., obs_dim)."""
    mask = observation_mask(mode, obs.shape[-1])
    if isinstance(obs, torch.Tensor):
        return obs * torch.tensor(mask)
    return np.asarray(obs, dtype=np.float32) * mask


class MultiAgentTrainer(DQNTrainer):
    """The course skeleton's trainer: the learner built from a bare ``argparse.Namespace``
    (``mode`` missing or ``all`` means ``full``; other attributes, e.g. ``grid_size``, are
    read from the environment) with ``select_action``, ``train_episode``, ``evaluate`` and
    ``network_A`` / ``network_B`` on top."""

    def __init__(self, env: Any, args: Any) -> None:
        known = {f.name for f in dataclasses.fields(TrainConfig)}
        settings = {k: v for k, v in vars(args).items() if k in known and v is not None}
        if settings.get("mode", "all") == "all":
            settings["mode"] = "full"
        settings.setdefault("output_dir", "results")  # like the skeleton
        # The skeleton plays its own episodes (train_episode): no budget to check.
        super().__init__(env, validated(TrainConfig(**settings), whole_run=False))
        self._episode_rollout = self.start_rollout(1, self.seed + 1)  # train_episode's env

    network_A = property(lambda self: self.online.agent(0), doc="A's network (a copy)")
    network_B = property(lambda self: self.online.agent(1), doc="B's network (a copy)")

    def select_action(
        self, state: np.ndarray, network: torch.nn.Module, epsilon: float
    ) -> tuple[int, float]:
        """ε-greedy action and message of one agent: ``state`` (obs_dim,) raw observation."""
        masked = torch.as_tensor(state, dtype=torch.float32) * self.mask
        with torch.no_grad():
            q_values, comm = network(masked.unsqueeze(0))
        action = int(q_values.argmax(dim=1).item())
        if self.rng.random() < epsilon:
            action = int(self.rng.integers(NUM_ACTIONS))
        return action, float(comm.item())

    def train_episode(self) -> tuple[float, bool]:
        """Play one episode in one environment, learning as ``train`` does but with one
        gradient update per env step (the skeleton's loop); returns (episode_reward, success)."""
        while True:
            returns, successes, finished = self.collect(self._episode_rollout)
            if self.env_steps >= self.cfg.learning_starts:
                self.update_networks(self.cfg.batch_size)
            self.update_schedules(int(finished.sum()))
            if len(returns):
                return float(returns[0]), bool(successes[0])

    def evaluate(
        self, num_episodes: int = 10, epsilon: float = 0.0, seed: int = EVAL_SEED
    ) -> tuple[float, float]:
        """(mean reward, success rate) over fixed episodes (the test episodes by default),
        under the reward the trainer learns from (unshaped)."""
        summary = self.evaluation_summary(num_episodes, epsilon, seed)
        return summary["mean_return"], summary["success_rate"]


# ------------------------------------------------------------------ one run, then the batch
def train_one(
    cfg: TrainConfig, mode: str, seed: int, staging: Path, trainer_class: type = DQNTrainer
) -> dict[str, Any]:
    """Train ``mode`` with ``seed`` into ``staging``'s agent_models/ and training_logs/, then
    evaluate it on ``final_eval_episodes`` validation episodes, greedy and at ε = 0.05 (what
    picks each mode's best seed; the reported results come from evaluate.py)."""
    torch.set_num_threads(1)  # runs go in parallel, one per core
    run_cfg = dataclasses.replace(cfg, mode=mode, seed=seed, seeds=[], output_dir=str(staging))
    env = VectorMultiAgentEnv(  # the map: the trainer reads its grid, window and time limit
        1,
        grid_size=cfg.grid_shape(),
        max_steps=cfg.max_steps,
        seed=cfg.map_seed,
        reward_mode=cfg.reward_mode,
    )
    trainer = trainer_class(env, run_cfg)
    clock = {"start": time.perf_counter(), "shown": -math.inf}  # when the last line was printed
    trainer.train(lambda row: report_progress(trainer, row, clock))
    selection: dict[str, Any] = {"select_by": cfg.select_by, "validation_seed": VALIDATION_SEED}
    for label, epsilon in (("greedy", 0.0), ("eps", EVAL_EPSILON)):
        summary = trainer.evaluation_summary(cfg.final_eval_episodes, epsilon, VALIDATION_SEED)
        selection[label] = {"epsilon": epsilon, **summary}
    safety.write_json_atomic(
        trainer.logs_dir / f"{trainer.name}_selection.json",
        {"mode": mode, "seed": seed} | selection,
    )
    return {
        "mode": mode,
        "seed": seed,
        **selection,
        "seconds": time.perf_counter() - clock["start"],
    }


def report_progress(trainer: DQNTrainer, row: dict[str, Any], clock: dict[str, float]) -> None:
    """After each periodic evaluation: the intermediate save (``--save_freq``) and, every ~10 s
    and at the end, one plain line (runs in parallel print their own lines)."""
    cfg = trainer.cfg
    if cfg.save_freq and row["env_steps"] % cfg.save_freq < cfg.eval_interval:
        trainer.save_models()
    elapsed, done = time.perf_counter() - clock["start"], trainer.progress()
    if done < 1 and elapsed < clock["shown"] + 10:
        return
    clock["shown"] = elapsed
    eta = f", ETA {elapsed * (1 - done) / done:.0f} s" if done else ""  # none before a step
    print(
        f"{trainer.name}: {row['env_steps']:,} env steps ({done:.0%}), "
        f"{row['env_steps'] / max(elapsed, 1e-9):,.0f} steps/s, epsilon {row['epsilon']:.2f}, "
        f"validation success {row['eval_success_eps']:.2f}{eta}",
        flush=True,
    )


def best_runs(cfg: TrainConfig, finals: list[dict[str, Any]]) -> dict[str, str]:
    """Each mode's best run (``<mode>_seed<seed>``): the seed ``select_by`` picks on the
    validation episodes (:func:`rollout.select_best`)."""
    best = {}
    for mode in cfg.run_modes():
        runs = sorted((f for f in finals if f["mode"] == mode), key=lambda f: f["seed"])
        winner = runs[select_best([(f["greedy"], f["eps"]) for f in runs], cfg.select_by)]
        best[mode] = f"{mode}_seed{winner['seed']}"
    return best


def read_csv(path: Path) -> list[dict[str, float]]:
    with open(path, newline="", encoding="utf-8") as handle:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]


# ------------------------------------------------------------------ the curves
RETURN_NAMES = {  # reward_mode -> the return the curves show when no table return was logged
    "goal": "goal reward",
    "per_step": "assignment's reward",
    "arrival": "arrival reward",
}


def plot_training_curves(
    logs_dir: Path, modes: list[str], seeds: list[int], settings: dict[str, Any]
) -> None:
    """Validation success and return at ε = 0.05 and the TD loss against env steps, the modes
    overlaid: the mean over seeds and the interquartile band, 6.5 in wide as the report prints
    it. The return is under the assignment's table (+10 / +2 / −0.1) where the logs hold it,
    else under the reward the batch learnt from (``settings["reward_mode"]``), named on the
    axis; the loss is the mean of the updates since the previous evaluation (log scale)."""
    from matplotlib.figure import Figure  # here: a worker process never needs matplotlib
    from matplotlib.ticker import MaxNLocator

    logs = {m: [read_csv(logs_dir / f"{m}_seed{s}.csv") for s in seeds] for m in modes}
    table = all("eval_return_table_eps" in log[0] for runs in logs.values() for log in runs)
    reward = "assignment's reward" if table else RETURN_NAMES[settings["reward_mode"]]
    panels = (
        ("eval_success_eps", "success (%)"),
        ("eval_return_table_eps" if table else "eval_return_eps", f"return\n({reward})"),
        ("loss", "TD loss (training)"),
    )
    fig = Figure(figsize=(6.5, 2.5), layout="constrained")
    for ax, (key, label) in zip(fig.subplots(1, 3, sharex=True), panels, strict=True):
        for mode, runs in logs.items():
            length = min(len(log) for log in runs)
            steps = np.array([row["env_steps"] for row in runs[0][:length]]) / 1000
            values = np.array([[row[key] for row in log[:length]] for log in runs])
            values = 100 * values if key == "eval_success_eps" else values
            low, high = np.percentile(values, [25, 75], axis=0)
            ax.fill_between(steps, low, high, color=MODE_COLOURS[mode], alpha=0.3, linewidth=0)
            ax.plot(steps, values.mean(axis=0), color=MODE_COLOURS[mode], lw=1.4, label=mode)
        if key == "loss":
            ax.set_yscale("log")
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.set_xlabel("env steps (thousands)", fontsize=9)
        ax.set_ylabel(label, fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=8)
    title = f"mean of {len(seeds)} seeds (band: middle half)"
    fig.legend(
        *ax.get_legend_handles_labels(),
        loc="outside upper center",
        ncols=len(logs),
        fontsize=8,
        frameon=False,
        title=title,
        title_fontsize=8,
    )
    with safety.temporary_path_for(logs_dir / "training_curves.png") as temporary:
        fig.savefig(temporary, format="png", dpi=300)  # printed 6.5 in wide: 300 ppi


def main(
    argv: list[str] | None = None, cfg: TrainConfig | None = None, trainer_class: type = DQNTrainer
) -> list[dict[str, Any]]:
    """Train every requested mode and seed and write the models, logs and curves of the batch.
    Every setting (``argv``, or a study's checked ``cfg`` and learner) and the output folder
    are checked before any work (a bad one: a usage error naming the flag, exit status 2)."""
    safety.use_reproducible_matmul()  # before the first matrix product
    safety.make_console_safe()
    parser = build_parser(
        prog="train.py",
        description="Train the two agents (Problem 2).",
        epilog=OUTPUT_RULE,
        formatter_class=argparse.RawDescriptionHelpFormatter,  # the epilog's paragraphs kept
    )
    try:  # a bad setting or folder: one line each, naming the flag (exit status 2)
        cfg = parse_config(argv, parser) if cfg is None else validated(cfg)
        root = Path(cfg.output_dir).resolve()
        default = TrainConfig().identity()
        output_folder.check_output_dir(
            root, cfg.identity(), cfg.overwrite, DEFAULT_OUTPUT_DIR, default
        )
    except SettingError as error:
        parser.error(usage(error))
    except output_folder.FolderError as error:
        parser.error(f"argument --output_dir: {error}, got {cfg.output_dir!r}")
    runs = [(mode, seed) for mode in cfg.run_modes() for seed in cfg.run_seeds()]
    workers = min(cfg.workers, len(runs))
    print(f"training {len(runs)} runs into {safety.shown(root)} ({workers} at a time)")
    with output_folder.staged_batch(root) as staging:
        models = staging / "agent_models"
        grid = generate_map(cfg.grid_shape(), cfg.map_seed)
        safety.write_json_atomic(models / "map.json", {"grid": grid.tolist()})
        safety.write_json_atomic(models / "hyperparameters.json", cfg.hyperparameters())
        if workers == 1:
            finals = [train_one(cfg, mode, seed, staging, trainer_class) for mode, seed in runs]
        else:  # one run per process; the results in the order of the runs
            context = multiprocessing.get_context("spawn")
            jobs = [(cfg, mode, seed, staging, trainer_class) for mode, seed in runs]
            with context.Pool(workers, output_folder.start_worker) as pool:
                finals = pool.starmap(train_one, jobs, chunksize=1)
        best = best_runs(cfg, finals)
        logs = staging / "training_logs"
        plot_training_curves(logs, cfg.run_modes(), cfg.run_seeds(), cfg.hyperparameters())
        output_folder.record_batch(staging, finals, best, cfg.identity(), cfg.select_by)
    output_folder.keep_out_of_git(root, DEFAULT_OUTPUT_DIR)
    for final in finals:
        name = f"{final['mode']}_seed{final['seed']}"
        print(
            f"{name:<22} validation success greedy {final['greedy']['success_rate']:.3f}, "
            f"epsilon 0.05 {final['eps']['success_rate']:.3f}"
            + (" (best)" * (name in best.values()))
        )
    print(f"wrote {safety.shown(root)} (evaluate.py tests the models on other episodes)")
    return finals


OUTPUT_RULE = """\
Outputs (in --output_dir): agent_models/ (TorchScript pairs, manifest.json, map.json,
hyperparameters.json) and training_logs/ (one CSV per run, <run>_selection.json,
training_curves.png, timing.json).

A batch is written into a hidden staging folder inside --output_dir and moved into place
only when every run has finished, so the folder holds one whole batch or the previous one.
Into a folder that holds a batch with other settings (or model files without a manifest)
training refuses unless --overwrite is given; a re-run with identical settings replaces
it. Settings other than the defaults never go into the default folder without --overwrite
(choose another --output_dir). A folder of other files, or one inside the code (e.g.
analysis), is refused even with --overwrite. A replaced batch's evaluation_results/ goes
with it (unless the new models are byte-identical): run evaluate.py again. Interrupted
with Ctrl-C, the batch leaves the evaluation rows it measured in
<output_dir>/interrupted/<n>/training_logs/ and the results untouched.
Stale temporary files of killed runs are removed at the next start."""


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:  # the measured rows were kept (staged_batch)
        sys.exit(130)
