"""Is the panel's recipe still learning at its end? Twice the steps on the panel's hardest map.

    python -m studies.panel_long     # after python -m studies.panel (reads panel.json)

The hardest map is the one where full agents succeed least at ε = 0.05 in the panel (a rule
fixed before this check: the first such map in the panel's order on a tie). Full agents are
trained there with the main experiment's recipe but twice its env steps, on the panel's
training seeds, and tested with the panel's protocol (1000 fixed test episodes per seed,
greedy and at ε = 0.05). Writes ``panel/long/map<seed>/`` (a train.py batch) and
``panel/long/panel_long.json``: the success of both budgets, their difference paired by
training seed, and the validation curve of the long runs at the panel's budget and at their
end. No setting of the panel itself changes: this check stands beside it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import train
from analysis.pipeline import CONDITIONS, evaluate_experiment
from analysis.runs import read_experiment
from analysis.stats import seed_paired_differences, seed_statistics
from rollout import EVAL_EPSILON
from settings import TrainConfig
from train import read_csv

from studies.panel import PANEL_DIR
from studies.staging import run_command

BUDGET_FACTOR = 2
MODE = "full"


def hardest_map(panel: dict[str, Any]) -> int:
    """The panel map where full succeeds least at ε (the first in the panel's order on a tie)."""
    maps = panel["protocol"]["map_seeds"]
    return min(maps, key=lambda m: panel["maps"][str(m)]["success"][MODE]["eps"]["mean"])


def validation_at(logs_dir: Path, seeds: list[int], env_steps: int) -> dict[str, Any]:
    """Validation success at ε of each seed's last evaluation at or before ``env_steps``."""
    values = []
    for seed in seeds:
        rows = read_csv(logs_dir / f"{MODE}_seed{seed}.csv")
        values.append([r for r in rows if r["env_steps"] <= env_steps][-1]["eval_success_eps"])
    return seed_statistics(values)


def run_check(panel_dir: Path, num_episodes: int, total_steps: int) -> dict[str, Any]:
    """Train and test the long runs; the summary that ``panel_long.json`` holds."""
    panel = json.loads((panel_dir / "panel.json").read_text(encoding="utf-8"))
    map_seed = hardest_map(panel)
    seeds = panel["maps"][str(map_seed)]["seeds"][MODE]
    default = TrainConfig()
    cfg = TrainConfig(
        mode=MODE,
        map_seed=map_seed,
        seeds=list(seeds),
        total_steps=total_steps,
        overwrite=True,
        output_dir=str(panel_dir / "long" / f"map{map_seed}"),
    )
    train.main(cfg=cfg)  # checks every setting first
    batch = Path(cfg.output_dir)
    experiment = read_experiment(f"panel/long/map{map_seed}", batch / "agent_models")
    outcome = evaluate_experiment(experiment, num_episodes, EVAL_EPSILON)
    long_success = {c: outcome.performance["modes"][MODE][c]["success_rate"] for c in CONDITIONS}
    short_success = panel["maps"][str(map_seed)]["success"][MODE]
    per_seed = {
        (label, seed): {c: success[c]["per_seed"][i] for c in CONDITIONS}
        for label, success in (("long", long_success), ("panel", short_success))
        for i, seed in enumerate(seeds)
    }
    difference = seed_paired_differences(per_seed, [("long", "panel")], CONDITIONS)
    return {
        "rule": "the panel map where full succeeds least at eps; full agents, the main "
        "experiment's recipe with more env steps, the panel's seeds",
        "map_seed": map_seed,
        "seeds": seeds,
        "total_steps": {"panel": default.total_steps, "long": cfg.total_steps},
        "test_success": {
            "panel": short_success,
            "long": long_success,
            "long_minus_panel": difference["long-panel"],
        },
        "validation_success_eps": {
            "at_panel_budget": validation_at(batch / "training_logs", seeds, default.total_steps),
            "at_end": validation_at(batch / "training_logs", seeds, cfg.total_steps),
        },
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--panel_dir", "--panel-dir", type=Path, default=PANEL_DIR)
    parser.add_argument("--num_episodes", "--num-episodes", type=int, default=1000)
    parser.add_argument(
        "--total_steps",
        "--total-steps",
        type=int,
        default=BUDGET_FACTOR * TrainConfig().total_steps,
        help="env steps per long run (default: twice the panel's)",
    )
    args = parser.parse_args(argv)
    if not (args.panel_dir / "panel.json").is_file():
        parser.error(f"--panel_dir {args.panel_dir}: no panel.json (run python -m studies.panel)")
    if not 1 <= args.num_episodes <= 5000:
        parser.error(f"--num_episodes must be an integer in 1..5000, got {args.num_episodes}")
    if args.total_steps < 1:
        parser.error(f"--total_steps must be an integer >= 1, got {args.total_steps}")
    results = run_check(args.panel_dir, args.num_episodes, args.total_steps)
    write_json_atomic(args.panel_dir / "long" / "panel_long.json", results)
    print(json.dumps(results["test_success"], indent=1))
    print(f"wrote {args.panel_dir / 'long'}")
    return results


if __name__ == "__main__":
    run_command(main)
