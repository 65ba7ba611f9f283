"""Problem 2 learner speed: ms per gradient update and env-steps/s of training, one thread.

For each checkout given with ``--repo`` (default: this one) it measures, in a fresh
process per repeat (checkouts are interleaved so that a busy machine slows all alike):

* ``update independent`` / ``update full``: ms per ``update_networks(256)`` of networks
  with 64 hidden units (the same work in every checkout) on a buffer filled by 6 400 env
  steps of the default map (``full`` learns its messages with DIAL);
  ``update full, defaults``: the same at the checkout's default batch size and hidden units;
* ``training``: env-steps/s of ``train()`` at the checkout's default settings for 40 000
  env steps, evaluation switched off;
* with ``--end_to_end``: wall seconds of ``python train.py --mode full --num_seeds 1
  --workers 1`` (one default run of the checkout, with its periodic evaluation and export).

It prints the median over the repeats and, for every further checkout, its ratio to the
first. Compare against an older commit side by side, e.g.:

    git worktree add ../base ac32b54
    python bench/p2_update.py --repo ../base --repo . --repeats 5 --end_to_end
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent.parent
BATCH_SIZE = 256
HIDDEN_DIM = 64
FILL_STEPS = 6_400
TRAIN_STEPS = 40_000


def measure(repo: Path, updates: int) -> dict[str, float]:
    """Run in a child process: import the trainer of ``repo`` and time it."""
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, str(repo / "problem2"))
    from multi_agent_env import MultiAgentEnv
    from settings import TrainConfig

    try:  # the core learner; older checkouts named their trainer MultiAgentTrainer
        from trainer import DQNTrainer as Trainer
    except ImportError:
        from trainer import MultiAgentTrainer as Trainer

    known = TrainConfig.__dataclass_fields__
    results: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as scratch:
        os.chdir(scratch)  # a checkout that writes files from train() writes them here

        def trainer_for(mode: str, **settings: object) -> Trainer:
            settings = {"mode": mode, "eval_episodes": 10, "output_dir": scratch} | settings
            cfg = TrainConfig(**{k: v for k, v in settings.items() if k in known})
            return Trainer(MultiAgentEnv(seed=641), cfg)

        def filled(mode: str, **settings: object) -> Trainer:
            trainer = trainer_for(
                mode,
                total_steps=FILL_STEPS,
                learning_starts=10**9,
                eval_interval=10**9,
                keep_best=False,
                **settings,
            )
            trainer.train()
            for _ in range(20):  # warm up
                trainer.update_networks(BATCH_SIZE)
            return trainer

        for mode in ("independent", "full"):
            trainer = filled(mode, hidden_dim=HIDDEN_DIM)
            results[f"update {mode} (ms)"] = ms_per_update(trainer, BATCH_SIZE, updates)
        results["update full, defaults (ms)"] = ms_per_update(
            filled("full"), TrainConfig().batch_size, updates
        )

        trainer = trainer_for("full", total_steps=TRAIN_STEPS, eval_interval=10**9)
        start = time.perf_counter()
        trainer.train()
        results["training (env-steps/s)"] = TRAIN_STEPS / (time.perf_counter() - start)
    return results


def ms_per_update(trainer: Any, batch_size: int, updates: int) -> float:
    """Milliseconds per ``trainer.update_networks(batch_size)``, over ``updates`` calls."""
    start = time.perf_counter()
    for _ in range(updates):
        trainer.update_networks(batch_size)
    return (time.perf_counter() - start) / updates * 1e3


def end_to_end(repo: Path) -> float:
    """Wall seconds of one default full run of ``repo``'s train.py (in a scratch folder)."""
    with tempfile.TemporaryDirectory() as scratch:
        command = [sys.executable, "train.py", "--mode", "full", "--num_seeds", "1"]
        command += ["--workers", "1", "--output_dir", str(Path(scratch) / "out")]
        environment = os.environ | {"OMP_NUM_THREADS": "1", "PYTHONIOENCODING": "utf-8"}
        start = time.perf_counter()
        subprocess.run(
            command,
            cwd=repo / "problem2",
            env=environment,
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--repo", action="append", type=Path, help="checkout (repeatable)")
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes per checkout")
    parser.add_argument("--updates", type=int, default=500, help="timed updates per mode")
    parser.add_argument("--end_to_end", "--end-to-end", action="store_true")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.repeats < 1 or args.updates < 1:
        parser.error("--repeats and --updates must be positive")
    if args.child:
        print(json.dumps(measure(args.child, args.updates)))
        return
    repos = [repo.resolve() for repo in (args.repo or [HERE])]
    for repo in repos:
        if not (repo / "problem2" / "trainer.py").is_file():
            parser.error(f"--repo {repo} has no problem2/trainer.py")
    samples: dict[Path, dict[str, list[float]]] = {repo: {} for repo in repos}
    for repeat in range(args.repeats):
        for repo in repos:
            command = [sys.executable, __file__, "--child", str(repo)]
            command += ["--updates", str(args.updates)]
            output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
            figures = json.loads(output.strip().splitlines()[-1])
            if args.end_to_end:
                figures["one default full run (s)"] = end_to_end(repo)
            for name, value in figures.items():
                samples[repo].setdefault(name, []).append(value)
            print(f"repeat {repeat + 1}/{args.repeats} {repo.name}: {figures}", file=sys.stderr)
    names = list(samples[repos[0]])
    header = f"{'median of ' + str(args.repeats):<28}" + "".join(f"{r.name:>14}" for r in repos)
    print(header + ("".join(f"{'ratio':>10}" for _ in repos[1:])))
    for name in names:
        medians = [statistics.median(samples[repo][name]) for repo in repos]
        line = f"{name:<28}" + "".join(f"{m:14.3f}" for m in medians)
        for median in medians[1:]:  # speed-up: bigger is better for rates, smaller for times
            ratio = median / medians[0] if "/s" in name else medians[0] / median
            line += f"{ratio:9.2f}x"
        print(line)


if __name__ == "__main__":
    main()
