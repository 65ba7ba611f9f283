"""Train the two agents of Problem 2: every ablation mode, several seeds, in parallel.

    python train.py                      # 3 modes x 5 seeds on the default map (seed 641)
    python train.py --mode full --seeds 641 642 --total_steps 200000
    python train.py --help               # every hyperparameter, with its meaning

The learning algorithm is in ``trainer.py`` (:class:`MultiAgentTrainer`, re-exported
here with :func:`apply_observation_mask`), the hyperparameters in ``train_config.py``,
and the batch of runs with its outputs in ``experiments.py``.
"""

from __future__ import annotations

from typing import Any

from experiments import run_experiments
from train_config import TrainConfig, parse_config
from trainer import EVAL_EPSILON, MultiAgentTrainer, apply_observation_mask

__all__ = ["EVAL_EPSILON", "MultiAgentTrainer", "TrainConfig", "apply_observation_mask", "main"]


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """Train every requested mode and seed (in parallel) and write models, logs and curves."""
    cfg = parse_config(argv)
    finals = run_experiments(cfg)
    print(f"{'run':<22} {'success greedy':>15} {'success ε=0.05':>15}")
    for final in finals:
        print(
            f"{final['mode'] + ' seed ' + str(final['seed']):<22} "
            f"{final['greedy']['success_rate']:15.3f} {final['eps']['success_rate']:15.3f}"
        )
    return finals


if __name__ == "__main__":
    main()
