"""Train the two agents of Problem 2: every ablation mode, several seeds, in parallel.

    python train.py                      # 3 modes x 10 seeds on the default map (seed 641)
    python train.py --mode full --seeds 641 642 --total_steps 200000 --output_dir my_run
    python train.py --help               # every hyperparameter, with its meaning and range

The algorithm is in ``trainer.py`` (:class:`MultiAgentTrainer`, re-exported here), the
hyperparameters in ``train_config.py``, the batch in ``batch/experiments.py`` and the flags in
``batch/cli.py``; :func:`apply_observation_mask` is the course's masking function (the learner
applies the same mask, ``models.observation_mask``, inside its networks' inputs).
"""

from __future__ import annotations

import gc
import sys
from typing import Any

import numpy as np
import torch
from batch.cli import parse_config_or_exit
from batch.experiments import INTERRUPTED, check_output_dir, output_root, run_experiments
from batch.plumbing import make_console_safe
from models import observation_mask, use_reproducible_matmul
from train_config import TrainConfig
from trainer import EVAL_EPSILON, MultiAgentTrainer

__all__ = ["EVAL_EPSILON", "MultiAgentTrainer", "TrainConfig", "apply_observation_mask", "main"]


def apply_observation_mask(obs: np.ndarray | torch.Tensor, mode: str) -> np.ndarray | torch.Tensor:
    """Zero the inputs that ablation ``mode`` hides (``models.MASKED_INPUTS``):
    ``independent`` the message and the distance (elements 9 and 10 for a 3 x 3 window),
    ``comm`` the distance, ``distance`` the message, ``full`` none. Any leading shape
    (..., obs_dim)."""
    mask = observation_mask(mode, obs.shape[-1])
    if isinstance(obs, torch.Tensor):
        return obs * torch.tensor(mask)
    return np.asarray(obs, dtype=np.float32) * mask


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """Train every requested mode and seed (in parallel) and write models, logs and curves.
    Every setting and the output folder are checked first (a usage error names the flag)."""
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    cfg = parse_config_or_exit(argv, extra_check=check_output_dir)
    try:
        finals = run_experiments(cfg)
    except KeyboardInterrupt:
        kept = output_root(cfg) / INTERRUPTED / "training_logs"
        print(f"\ninterrupted: the rows measured so far are in {kept}", file=sys.stderr)
        raise
    print(f"{'run':<22} {'selection: success greedy':>26} {'eps=0.05':>9}")
    for final in finals:
        print(
            f"{final['mode'] + ' seed ' + str(final['seed']):<22} "
            f"{final['greedy']['success_rate']:26.3f} {final['eps']['success_rate']:9.3f}"
        )
    print(f"wrote {output_root(cfg)} (success on validation episodes; evaluate.py tests)")
    return finals


if __name__ == "__main__":
    # Frozen, the modules' objects (torch alone has ~170 k) are skipped by the collector's full
    # passes during the run and at exit (~0.3 s sooner); freezing again adds what the run imported.
    gc.freeze()
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
    gc.freeze()
