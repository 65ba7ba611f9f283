"""Evaluate Problem 2's trained agents: honest success rates, what the message means, how
the agents fail, other maps, and pictures.

    python evaluate.py                               # every mode and seed found, all studies
    python evaluate.py --checkpoint results/agent_models --num_episodes 1000 --epsilon 0.05
    python evaluate.py --render                      # also print one episode step by step

Models are loaded as TorchScript files only (``torch.jit.load``), never through the
training code, so models exported elsewhere are evaluated the same way. Every policy runs
on the vectorised environment, all test episodes of a model in one batch, with fixed start
cells (seed 7 000 000, as the trainer's final evaluation), greedy (ε = 0) and ε-greedy with
a seeded exploration stream.

The course interface lives here: :func:`load_trained_models`, :class:`MultiAgentEvaluator`
(``analysis_evaluator.py``) and :func:`create_evaluation_report` (``analysis_report.py``).
The run of ``python evaluate.py`` is in ``analysis_pipeline.py``; it writes to
``<checkpoint>/../evaluation_results/`` (``results/evaluation_results/`` by default):
``performance.json``, ``comparison_table.md``, ``communication_analysis.json``,
``failure_analysis.json``, ``generalization.json``, ``trajectories.png``,
``comm_heatmap.png`` and ``episode_<mode>.gif``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import torch
from analysis_evaluator import MultiAgentEvaluator
from analysis_pipeline import evaluate_all, write_outputs
from analysis_report import create_evaluation_report, format_report
from analysis_runs import DEFAULT_ROOT, discover_experiments, load_model_pair
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_EPSILON

__all__ = ["MultiAgentEvaluator", "create_evaluation_report", "load_trained_models", "main"]


def load_trained_models(
    checkpoint_dir: str | Path = DEFAULT_ROOT / "agent_models",
    mode: str = "full",
    seed: int | None = None,
) -> tuple[torch.jit.ScriptModule, torch.jit.ScriptModule]:
    """Load (model_A, model_B) of ``mode`` from ``checkpoint_dir``: the best pair
    ``<mode>_agent_{A,B}.pt``, or ``<mode>_seed<seed>_agent_{A,B}.pt`` if ``seed`` is given.

    Raises FileNotFoundError (naming the directory or file) if one is missing and
    ValueError (naming the file) if it is not a TorchScript policy of the right shape."""
    return load_model_pair(Path(checkpoint_dir), mode, seed)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add = parser.add_argument
    add("--checkpoint", "--checkpoint_dir", type=Path, default=DEFAULT_ROOT / "agent_models",
        help="agent_models folder of the main experiment; studies are found beside it "
             "under ../studies (default: results/agent_models)")  # fmt: skip
    add("--num_episodes", "--num-episodes", type=int, default=1000,
        help="test episodes per trained seed and condition (default 1000)")  # fmt: skip
    add("--epsilon", type=float, default=EVAL_EPSILON,
        help="exploration rate of the ε-greedy condition (default 0.05)")  # fmt: skip
    add("--render", action="store_true", help="first print one episode step by step")
    add("--mode", default="full", choices=("independent", "comm", "full"),
        help="mode whose best pair --render shows (default full)")  # fmt: skip
    add("--output_dir", "--output-dir", type=Path, default=None,
        help="output folder (default: evaluation_results beside the checkpoint)")  # fmt: skip
    add("--generalization_episodes", "--generalization-episodes", type=int, default=500,
        help="test episodes per model and map, generalisation test (default 500)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.num_episodes < 1 or args.generalization_episodes < 1:
        parser.error("episode counts must be positive")
    if not 0 <= args.epsilon <= 1:
        parser.error(f"--epsilon must lie in [0, 1], got {args.epsilon}")
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Evaluate every experiment found from the checkpoint folder and write every output."""
    args = parse_args(argv)
    torch.set_num_threads(1)  # batches of ~1000 rows: one thread is fast and leaves cores free
    checkpoint = args.checkpoint.resolve()
    if not checkpoint.is_dir():
        raise FileNotFoundError(f"checkpoint directory {checkpoint} does not exist")
    experiments = discover_experiments(checkpoint)
    if not experiments:
        raise FileNotFoundError(
            f"no trained models (<mode>_seed<seed>_agent_A.pt) in {checkpoint}; run train.py first"
        )
    if args.render:
        main_experiment = experiments[0]
        env = MultiAgentEnv(
            grid=main_experiment.grid,
            max_steps=int(main_experiment.settings["max_steps"]),
            reward_mode=main_experiment.settings["reward_mode"],
        )
        models = load_trained_models(main_experiment.models_dir, args.mode)
        print(f"one greedy episode of the best {args.mode} pair ({main_experiment.models_dir}):")
        MultiAgentEvaluator(env, *models).run_episode(render=True)
    results, outcomes = evaluate_all(experiments, args)
    output_dir = args.output_dir or checkpoint.parent / "evaluation_results"
    write_outputs(results, outcomes, output_dir)
    print(format_report(results, brief=True))
    print(f"wrote {output_dir}")
    return results


if __name__ == "__main__":
    main()
