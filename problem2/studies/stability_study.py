"""Does learning hold its peak? The training curves of five settings on training seeds.

    python -m studies.stability_study --train      # train the five batches, then summarise
    python -m studies.stability_study              # summarise the batches already trained

Each setting is one ``train.py`` batch (3 modes x training seeds 100-103, the main
experiment's settings otherwise, ``--no-keep_best`` so that every run ends with its last
weights) in ``results/studies/stability/<setting>/``; ``CANDIDATES`` lists the flags. This
module reads their validation logs and writes ``stability.json``: per setting and mode, each
run's best and final validation success at ε = 0.05, the largest fall from a run's best to
its end, and the mean curve's first step at >= 95 % and its lowest value from then on;
and what each run's last weights do on ``DIAGNOSIS_EPISODES`` greedy validation episodes:
success, the gap between the best and the second-best action's value (median over the
states visited, both agents), the share of steps on which an agent off the target chose an
action that left it in place (Stay, or a move into a wall or an obstacle), and how often the
agents stepped onto the target per failed episode.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
import train
from analysis.arrivals import arrivals
from analysis.episodes import EvaluationSetting, model_policy, recorded_episodes
from analysis.runs import load_map, load_model_pair
from rollout import VALIDATION_SEED
from settings import MODES
from train import read_csv

from studies.staging import run_command

STUDY_DIR = Path(__file__).resolve().parent.parent / "results" / "studies" / "stability"
SEEDS = (100, 101, 102, 103)  # training seeds: never the reported 641-650
CANDIDATES = {
    "arrival_plain": {
        "flags": "--reward_mode arrival --target_potential 0 --advantage_learning 0",
        "words": "arrival reward (+2 on an agent's first arrival), plain Double-DQN target",
    },
    "arrival_al": {
        "flags": "--reward_mode arrival --target_potential 0",
        "words": "arrival reward, advantage learning",
    },
    "potential_plain": {
        "flags": "--advantage_learning 0",
        "words": "goal reward + each agent's own arrival term, plain Double-DQN target",
    },
    "team_potential_al": {
        "flags": "--potential_credit team",
        "words": "goal reward + the team's arrival term (both agents' arrivals), advantage "
        "learning",
    },
    "potential_al": {
        "flags": "",
        "words": "goal reward + each agent's own arrival term, advantage learning (the default)",
    },
}
COMMON_FLAGS = "--no-keep_best --final_eval_episodes 200 --overwrite"
HOLD_LEVEL = 0.95  # the mean curve's level that counts as learned
DIAGNOSIS_EPISODES = 500


def diagnose(models_dir: Path, mode: str, seed: int) -> dict[str, float | None]:
    """What the last weights of run (``mode``, ``seed``) do (see the module docstring)."""
    setting = EvaluationSetting(load_map(models_dir / "map.json"))
    target = setting.target
    models = load_model_pair(models_dir, mode, seed)
    env = setting.make_env(100)
    results = recorded_episodes(
        env, model_policy(*models), DIAGNOSIS_EPISODES, seed=VALIDATION_SEED
    )
    trajectories = results.trajectories
    taken = trajectories["actions"] >= 0  # (E, T, 2)
    gaps = []
    for agent, model in enumerate(models):
        obs = torch.from_numpy(trajectories["observations"][:, :-1, agent][taken[..., agent]])
        with torch.no_grad():
            top_two = model(obs)[0].topk(2, dim=-1).values
        gaps.append((top_two[:, 0] - top_two[:, 1]).numpy())
    positions = trajectories["positions"]  # (E, T + 1, 2, 2)
    before, after = positions[:, :-1], positions[:, 1:]
    off_target = ~np.all(before == np.asarray(target), axis=-1)
    in_place = np.all(before == after, axis=-1) & off_target & taken
    on = arrivals(positions, results.lengths, target).on.astype(int)
    entries = ((on[:, 1:] - on[:, :-1]) == 1).sum(axis=(1, 2))
    failed = ~results.successes
    return {
        "success": float(results.successes.mean()),
        "median_action_gap": float(np.median(np.concatenate(gaps))),
        "in_place_off_target_share": float(in_place.sum() / (off_target & taken).sum()),
        "arrivals_per_failed_episode": float(entries[failed].mean()) if failed.any() else None,
    }


def read_curve(path: Path) -> tuple[list[int], list[float]]:
    """(env steps, validation success at ε) of one run's log."""
    rows = read_csv(path)
    return [int(r["env_steps"]) for r in rows], [r["eval_success_eps"] for r in rows]


def summarise_mode(logs_dir: Path, mode: str) -> dict[str, Any]:
    """The measures of one setting's runs of ``mode`` (see the module docstring)."""
    curves = {seed: read_curve(logs_dir / f"{mode}_seed{seed}.csv") for seed in SEEDS}
    steps = curves[SEEDS[0]][0]
    length = min(len(c[1]) for c in curves.values())
    mean = [sum(c[1][k] for c in curves.values()) / len(curves) for k in range(length)]
    reached = next((k for k in range(length) if mean[k] >= HOLD_LEVEL), None)
    models_dir = logs_dir.parent / "agent_models"
    runs = {
        str(seed): {"best": max(values), "final": values[-1], "fall": max(values) - values[-1]}
        | {"last_weights": diagnose(models_dir, mode, seed)}
        for seed, (_, values) in curves.items()
    }
    diagnoses = [r["last_weights"] for r in runs.values()]
    return {
        "runs": runs,
        "largest_fall": max(r["fall"] for r in runs.values()),
        "final_mean": sum(r["final"] for r in runs.values()) / len(runs),
        "final_lowest": min(r["final"] for r in runs.values()),
        "mean_curve": {"env_steps": steps[:length], "success_eps": mean},
        "mean_first_at_hold_level": None if reached is None else steps[reached],
        "mean_lowest_after": None if reached is None else min(mean[reached:]),
        "run_steps": steps[length - 1],
        "median_action_gap": float(np.median([d["median_action_gap"] for d in diagnoses])),
        "in_place_off_target_share": float(
            np.mean([d["in_place_off_target_share"] for d in diagnoses])
        ),
        # the most of any run
        "arrivals_per_failed_episode": max(
            (
                d["arrivals_per_failed_episode"]
                for d in diagnoses
                if d["arrivals_per_failed_episode"] is not None
            ),
            default=None,
        ),
    }


def main(argv: list[str] | None = None) -> int:
    use_reproducible_matmul()  # before the first matrix product
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n")[0])
    parser.add_argument("--study_dir", type=Path, default=STUDY_DIR)
    parser.add_argument("--train", action="store_true", help="train every setting first")
    args = parser.parse_args(argv)
    if args.train:
        for name, candidate in CANDIDATES.items():
            seeds = ["--seeds", *(str(seed) for seed in SEEDS)]
            flags = [*candidate["flags"].split(), *COMMON_FLAGS.split(), *seeds]
            train.main([*flags, "--output_dir", str(args.study_dir / name)])
    result: dict[str, Any] = {
        "seeds": list(SEEDS),
        "hold_level": HOLD_LEVEL,
        "measure": "validation success at epsilon = 0.05 (200 episodes every 10 k env steps)",
        "candidates": {},
    }
    for name, candidate in CANDIDATES.items():
        logs_dir = args.study_dir / name / "training_logs"
        if not logs_dir.is_dir():
            raise FileNotFoundError(f"{logs_dir}: train this setting first (make p2-studies)")
        result["candidates"][name] = candidate | {
            "modes": {mode: summarise_mode(logs_dir, mode) for mode in MODES}
        }
    write_json_atomic(args.study_dir / "stability.json", result)
    for name, entry in result["candidates"].items():
        shown = ", ".join(
            f"{m} {e['final_mean']:.3f} (lowest {e['final_lowest']:.3f}, "
            f"fall {e['largest_fall']:.3f})"
            for m, e in entry["modes"].items()
        )
        print(f"{name}: final success at eps {shown}")
    print(f"wrote {args.study_dir / 'stability.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_command(main))
