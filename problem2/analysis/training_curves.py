"""Redraw a trained batch's ``training_curves.png`` from its logs, without training.

    python -m analysis.training_curves                         # results/ (the main experiment)
    python -m analysis.training_curves results/studies/no_dial results/studies/reward/arrival

Each folder is a batch that ``python train.py`` installed: ``agent_models/manifest.json``
names its modes, seeds, map and settings, ``training_logs/`` holds one CSV per run. The
figure is :func:`train.plot_training_curves`, as at the end of training.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from safety import use_reproducible_matmul

from output_folder import MANIFEST
from settings import DEFAULT_OUTPUT_DIR
from train import plot_training_curves


def read_batch(batch_dir: Path) -> dict:
    """The batch's manifest, after checking that every run's log is there (FileNotFoundError
    naming what is missing)."""
    manifest = batch_dir / "agent_models" / MANIFEST
    if not manifest.is_file():
        raise FileNotFoundError(f"{batch_dir} is not a trained batch: no agent_models/{MANIFEST}")
    identity = json.loads(manifest.read_text(encoding="utf-8"))
    missing = [
        f"{mode}_seed{seed}.csv"
        for mode in identity["modes"]
        for seed in identity["seeds"]
        if not (batch_dir / "training_logs" / f"{mode}_seed{seed}.csv").is_file()
    ]
    if missing:
        raise FileNotFoundError(f"{batch_dir}/training_logs lacks {', '.join(missing)}")
    return identity


def redraw(batch_dir: Path, identity: dict) -> Path:
    """Rewrite ``batch_dir/training_logs/training_curves.png`` for the batch of manifest
    ``identity``; returns its path."""
    logs_dir = batch_dir / "training_logs"
    plot_training_curves(
        logs_dir, identity["modes"], identity["seeds"], identity["hyperparameters"]
    )
    return logs_dir / "training_curves.png"


def main(argv: list[str] | None = None) -> list[Path]:
    use_reproducible_matmul()  # before the first matrix product
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "batch_dirs",
        nargs="*",
        type=Path,
        default=[DEFAULT_OUTPUT_DIR],
        help="batch folders holding agent_models/ and training_logs/ (default: results)",
    )
    args = parser.parse_args(argv)
    batches = []
    for folder in args.batch_dirs:  # every folder checked before any figure is drawn
        try:
            batches.append((folder, read_batch(folder)))
        except FileNotFoundError as error:
            parser.error(str(error))
    written = [redraw(folder, identity) for folder, identity in batches]
    for path in written:
        print(f"wrote {path}")
    return written


if __name__ == "__main__":
    main()
