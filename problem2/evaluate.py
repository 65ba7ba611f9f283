"""Evaluate Problem 2's trained agents as the assignment asks: how often each mode succeeds,
what its messages say, and pictures of its episodes.

    python evaluate.py                               # the main experiment, every mode and seed
    python evaluate.py --checkpoint my_run           # a train.py --output_dir folder
    python evaluate.py --num_episodes 200 --render   # fewer episodes; print one step by step

It writes into ``evaluation_results/`` beside the agent_models folder: ``performance.json``
(per mode and trained seed: success rate, steps to success, return and the kinds of failed
episodes, greedy and ε-greedy, and the mean over seeds: the comparison of the modes),
``communication_analysis.json`` (per mode and seed: the messages' distribution and their
correlation with what the sender sees and where it stands) and ``trajectories.png`` (each
mode's best pair in a successful and a failed episode, and its messages per cell).

Every pair plays the same fixed test episodes (start cells and exploration draws from
``rollout.EVAL_SEED``; training chose its checkpoints on other episodes). Models load with
``torch.jit.load`` only, each checked on probe observations; with a batch ``manifest.json``
exactly its runs are evaluated, every file's sha256 checked. A bad model file (missing,
damaged, unlisted, wrong shape, NaN, a message outside [0, 1]) stops the run before anything
is written, naming the file (exit status 1).

The report's analyses (intervals over seeds, differences between modes, baselines,
interventions, information measures, other maps, the studies) are ``python -m
analysis.pipeline`` (``make p2-evaluate``): it writes these three files in full, every number
of this script's at the same place, and the rest of ``evaluation_results/``. A JSON file here
that already holds every number this script measured (as after ``make p2-evaluate``) is kept.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from safety import make_console_safe, shown, use_reproducible_matmul, write_json_atomic

import torch
from analysis.episodes import SUCCESS, mean_over_seeds
from analysis.evaluator import MultiAgentEvaluator, experiment_evaluator
from analysis.messages import FEATURE_DESCRIPTIONS, message_correlations, message_distribution
from analysis.plots import plot_trajectories, strategy_rows
from analysis.runs import (
    DEFAULT_CHECKPOINT,
    MODES,
    Experiment,
    best_seed,
    checked_args,
    experiment_info,
    load_model_pair,
    make_parser,
    model_paths,
    read_experiment,
)
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_SEED, EpisodeResults

__all__ = ["MultiAgentEvaluator", "create_evaluation_report", "load_trained_models", "main"]
CONDITIONS = ("greedy", "eps")  # ε = 0 and ε = --epsilon


def load_trained_models(
    checkpoint_dir: str | Path = "results/agent_models",
    mode: str = "full",
    seed: int | None = None,
) -> tuple[torch.jit.ScriptModule, torch.jit.ScriptModule]:
    """Load (model_A, model_B) of ``mode`` from ``checkpoint_dir``: the best pair
    ``<mode>_agent_{A,B}.pt``, or ``<mode>_seed<seed>_agent_{A,B}.pt`` if ``seed`` is given.

    A relative ``checkpoint_dir`` is resolved against the current folder; the default
    ``results/agent_models``, if absent there, means this package's results folder, so
    ``load_trained_models()`` works from any folder. Raises FileNotFoundError (naming the
    directory or file) if one is missing and ValueError (naming the file) if it is not a
    TorchScript policy of the right shape with finite outputs."""
    path = Path(checkpoint_dir)
    if str(checkpoint_dir) == "results/agent_models" and not path.is_dir():
        path = DEFAULT_CHECKPOINT
    return load_model_pair(path, mode, seed)


def create_evaluation_report(
    results: dict[str, Any], save_path: str | Path = "results/evaluation_report.json"
) -> Path:
    """Write ``results`` (any JSON-serialisable dict, e.g. what ``evaluate_performance`` or
    ``python evaluate.py`` returns) to ``save_path`` as indented UTF-8 JSON, atomically;
    the parent folder is created. NaN or Infinity is refused (ValueError): not JSON."""
    if not isinstance(results, dict):
        raise TypeError(f"results must be a dict, got {type(results).__name__}")
    write_json_atomic(save_path, results)
    return Path(save_path)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = make_parser(__doc__.split("\n\n")[0])
    parser.add_argument(
        "--render", action="store_true", help="first print one episode step by step"
    )
    parser.add_argument(
        "--mode", default="full", choices=MODES, help="mode whose best pair --render shows"
    )
    return checked_args(parser, argv)


def evaluate_mode(
    experiment: Experiment, mode: str, num_episodes: int, epsilon: float
) -> tuple[dict[str, Any], dict[str, Any], dict[str, EpisodeResults]]:
    """(performance entry, communication entry, best seed's episodes) of one mode: every
    seed's pair on the same test episodes, greedy and ε-greedy."""
    per_seed, messages, runs = {}, {}, {}
    for seed in experiment.seeds[mode]:
        evaluator = experiment_evaluator(experiment, epsilon, mode, seed)
        runs[seed] = evaluator.run_conditions(num_episodes)
        per_seed[str(seed)] = evaluator.summaries(runs[seed])
        messages[str(seed)] = {
            "messages": message_distribution(runs[seed]["greedy"]),
            "correlations": message_correlations(runs[seed]["greedy"], experiment.grid),
        }
    chosen = best_seed(experiment, mode)
    if chosen is None:  # no best-pair files: the best seed of this evaluation
        chosen = max(runs, key=lambda s: per_seed[str(s)]["eps"]["success_rate"])
    label = experiment.label(mode)
    performance = {"label": label, "seeds": experiment.seeds[mode], "best_seed": chosen}
    for condition in CONDITIONS:
        summaries = [p[condition] for p in per_seed.values()]
        performance[condition] = {
            "epsilon": summaries[0]["epsilon"],
            "episodes_per_seed": summaries[0]["episodes"],
        } | {
            key: mean_over_seeds([s[key] for s in summaries])
            for key in ("success_rate", "mean_steps_to_success", "mean_return")
        }
    performance["per_seed"] = per_seed
    return performance, {"label": label, "per_seed": messages}, runs[chosen]


def evaluate_experiment(
    experiment: Experiment, num_episodes: int, epsilon: float
) -> tuple[dict[str, Any], dict]:
    """The contents of performance.json and communication_analysis.json, and each mode's
    best pair's episodes (for trajectories.png)."""
    protocol = {
        "evaluation_seed": EVAL_SEED,
        "episodes_per_seed": num_episodes,
        "conditions": {"greedy": 0.0, "eps": epsilon},
        "success": SUCCESS,
    }
    performance = experiment_info(experiment) | {"modes": {}}
    communication = {"map_seed": performance["map_seed"], "modes": {}}
    best_runs = {}
    for mode in experiment.seeds:
        performance["modes"][mode], communication["modes"][mode], best_runs[mode] = evaluate_mode(
            experiment, mode, num_episodes, epsilon
        )
        print(f"evaluated {mode}")
    results = {
        "performance": {"protocol": protocol, "experiments": {experiment.name: performance}},
        "communication": {
            "protocol": protocol | {"features": FEATURE_DESCRIPTIONS},
            "experiments": {experiment.name: communication},
        },
    }
    return results, best_runs


def holds(full: Any, part: Any) -> bool:
    """Whether ``full`` holds ``part``: every key of ``part`` with the same value, the
    values of its dicts compared the same way."""
    if isinstance(part, dict):
        return isinstance(full, dict) and all(
            k in full and holds(full[k], v) for k, v in part.items()
        )
    return full == part


def write_unless_held(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` to ``path`` unless the file there holds it (:func:`holds`): the fuller
    evaluation of ``python -m analysis.pipeline`` of the same models is kept."""
    try:
        kept = holds(json.loads(path.read_text(encoding="utf-8")), data)
    except (OSError, ValueError):
        kept = False
    if kept:
        print(f"{path.name}: the file there holds every number measured here; kept it")
    else:
        write_json_atomic(path, data)


def print_comparison(performance: dict[str, Any]) -> None:
    """The success rate of every mode, greedy and ε-greedy, as a table on the console."""
    print(f"{'mode':<14}{'seeds':>6}{'success greedy':>16}{'success ε':>11}{'steps ε':>9}")
    for mode, entry in performance["modes"].items():
        greedy, explored = entry["greedy"], entry["eps"]
        steps = explored["mean_steps_to_success"]["mean"]
        print(
            f"{mode:<14}{len(entry['seeds']):>6}{greedy['success_rate']['mean']:>16.3f}"
            f"{explored['success_rate']['mean']:>11.3f}"
            + (f"{steps:>9.1f}" if steps is not None else f"{'-':>9}")
        )


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Evaluate the main experiment's models and write the three files. A missing, damaged
    or unlisted model file ends the run (exit status 1) naming it, before anything is
    written: the manifest's checksums are checked when the experiment is read, and each
    pair is loaded and checked before it plays."""
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    args = parse_args(argv)
    torch.set_num_threads(1)  # batches of ~1000 rows: one thread is fast and leaves cores free
    try:
        experiment = read_experiment("main", args.checkpoint)
        if experiment is None:
            raise FileNotFoundError(f"no trained models in {args.checkpoint}; run train.py first")
        if experiment.manifest is None:
            print(f"note: no manifest.json in {args.checkpoint}: evaluating the model files found")
        if args.render:
            env = MultiAgentEnv(
                grid=experiment.grid,
                max_steps=int(experiment.settings["max_steps"]),
                reward_mode=experiment.settings["reward_mode"],
            )
            paths = model_paths(experiment.models_dir, args.mode)
            print(f"one greedy episode of the best {args.mode} pair ({paths[0]}, {paths[1]}):")
            models = load_trained_models(experiment.models_dir, args.mode)
            MultiAgentEvaluator(env, *models, names=tuple(map(str, paths))).run_episode(True)
        results, best_runs = evaluate_experiment(experiment, args.num_episodes, args.epsilon)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(f"evaluate.py: error: {error}") from error
    output_dir = args.output_dir or args.checkpoint.parent / "evaluation_results"
    performance = results["performance"]["experiments"]["main"]
    write_unless_held(output_dir / "performance.json", results["performance"])
    write_unless_held(output_dir / "communication_analysis.json", results["communication"])
    rows, messages = strategy_rows(best_runs, performance)
    plot_trajectories(rows, experiment.grid, output_dir / "trajectories.png", messages)
    print_comparison(performance)
    print(f"wrote {shown(output_dir)}")
    return results


if __name__ == "__main__":
    main()
