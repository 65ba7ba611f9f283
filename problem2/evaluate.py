"""Evaluate Problem 2's trained agents: the reported success rates, what each input channel
carries and what the agents use of it, how the agents fail, other maps, and pictures.

    python evaluate.py                               # every mode and seed, all studies
    python evaluate.py --checkpoint results/agent_models --num_episodes 1000 --epsilon 0.05
    python evaluate.py --checkpoint my_run           # a train.py --output_dir folder
    python evaluate.py --render                      # also print one episode step by step

The success rates reported anywhere come from here: fixed test episodes (start cells from
``rollout.EVAL_SEED``), greedy (ε = 0) and ε-greedy with exploration draws fixed per episode
and step. (Training picks checkpoints on other, validation episodes: that is "selection",
``training_logs/<run>_selection.json``, and is never reported as a result.) Models load
with ``torch.jit.load`` only; where the folder has a batch ``manifest.json``, exactly its
runs are evaluated and every file's sha256 is checked (else the files found are evaluated,
with a note). A bad model (missing, damaged, unlisted, NaN Q-values, a message outside
[0, 1]) stops the run before any output is written, naming the file (exit status 1).

The course interface lives here: :func:`load_trained_models`, :class:`MultiAgentEvaluator`
(``analysis/evaluator.py``) and :func:`create_evaluation_report` (``analysis/report.py``).
The run of ``python evaluate.py``: ``analysis/pipeline.py`` evaluates the training maps and
``analysis/generalization.py`` the other maps (episodes through ``rollout.run_episodes``;
measures from the recorded episodes: ``analysis/failures.py``, ``analysis/messages.py``,
``analysis/information.py``, ``analysis/interventions.py``, ``analysis/stats.py``), and
``analysis/outputs.py`` writes ``evaluation_results/`` beside the agent_models folder (see
that module for the list of files).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import safety  # noqa: F401  (first: checks the packages, stdlib only)
from safety import make_console_safe, use_reproducible_matmul

import torch
from analysis.evaluator import MultiAgentEvaluator
from analysis.outputs import write_outputs
from analysis.pipeline import evaluate_all
from analysis.report import create_evaluation_report, format_report
from analysis.runs import (
    DEFAULT_ROOT,
    MODES,
    discover_experiments,
    load_model_pair,
    model_paths,
    resolve_checkpoint,
)
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_EPSILON

__all__ = ["MultiAgentEvaluator", "create_evaluation_report", "load_trained_models", "main"]
DEFAULT_CHECKPOINT = DEFAULT_ROOT / "agent_models"


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


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description=__doc__.split("\n\n")[0],
        epilog="Relative paths are resolved against the current folder.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add = parser.add_argument
    add(
        "--checkpoint",
        "--checkpoint_dir",
        "--checkpoint-dir",
        type=Path,
        default=DEFAULT_CHECKPOINT,
        help="agent_models folder of the main experiment, or the run folder holding it "
        "(relative to the current folder; the default is this package's "
        "results/agent_models, from any folder). Studies are found beside it under "
        "../studies. With a manifest.json exactly its runs are evaluated, every file "
        "checked against it; without one, the model files found are",
    )
    add(
        "--num_episodes",
        "--num-episodes",
        type=int,
        default=1000,
        help="test episodes per trained seed and condition",
    )
    add(
        "--epsilon",
        type=float,
        default=EVAL_EPSILON,
        help="exploration rate of the ε-greedy condition",
    )
    add("--render", action="store_true", help="first print one episode step by step")
    add("--mode", default="full", choices=MODES, help="mode whose best pair --render shows")
    add(
        "--output_dir",
        "--output-dir",
        type=Path,
        default=None,
        help="output folder; None: evaluation_results beside the agent_models folder",
    )
    add(
        "--generalization_episodes",
        "--generalization-episodes",
        type=int,
        default=500,
        help="test episodes per model and map, generalisation test",
    )
    args = parser.parse_args(argv)
    for flag in ("num_episodes", "generalization_episodes"):
        if not 1 <= getattr(args, flag) <= 5000:
            parser.error(f"--{flag} must be an integer in 1..5000, got {getattr(args, flag)}")
    if not 0 <= args.epsilon <= 1:
        parser.error(f"--epsilon must lie in [0, 1], got {args.epsilon}")
    try:
        args.checkpoint, note = resolve_checkpoint(args.checkpoint)
    except ValueError as error:
        parser.error(str(error))
    if note:
        print(note)
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Evaluate every experiment found from the checkpoint folder and write every output.
    A missing, damaged or unlisted model file ends the run (exit status 1) naming it,
    before anything is written: the manifest's checksums are checked when the experiments
    are found, and each pair is loaded and checked where it is evaluated."""
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    args = parse_args(argv)
    torch.set_num_threads(1)  # batches of ~1000 rows: one thread is fast and leaves cores free
    try:
        experiments = discover_experiments(args.checkpoint)
        if not experiments:
            raise FileNotFoundError(f"no trained models in {args.checkpoint}; run train.py first")
        for experiment in experiments:
            if experiment.manifest is None:
                print(
                    f"note: no manifest.json in {experiment.models_dir}: evaluating the "
                    "model files found there"
                )
        if args.render:
            main_experiment = experiments[0]
            env = MultiAgentEnv(
                grid=main_experiment.grid,
                max_steps=int(main_experiment.settings["max_steps"]),
                reward_mode=main_experiment.settings["reward_mode"],
            )
            models = load_trained_models(main_experiment.models_dir, args.mode)
            names = tuple(str(p) for p in model_paths(main_experiment.models_dir, args.mode))
            print(f"one greedy episode of the best {args.mode} pair ({names[0]}, {names[1]}):")
            MultiAgentEvaluator(env, *models, names=names).run_episode(render=True)
        results, outcomes = evaluate_all(experiments, args)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(f"evaluate.py: error: {error}") from error
    output_dir = args.output_dir or args.checkpoint.parent / "evaluation_results"
    write_outputs(results, outcomes, output_dir)
    print(format_report(results, brief=True))
    print(f"wrote {output_dir}")
    return results


if __name__ == "__main__":
    main()
