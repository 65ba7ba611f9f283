"""The map panel: where does information enable coordination?

    python -m studies.panel          # after make p2-panel's training (train.py, one batch a map)
    python -m studies.panel --panel_dir /tmp/panel --maps 641,4 --num_episodes 200 --workers 1

The four modes form a 2 x 2 of what an agent sees beside its 3 x 3 patch: independent
(neither), comm (the partner's message), distance (the distance to the partner) and full
(both). On the assignment's map the target lies by a corner and every mode meets; maps whose
target lies in open ground can show what the channels are worth. The panel's maps follow a
rule fixed before any result (``MAP_RULE``): the assignment's map and the generator's first
11 map seeds. Each map's batch (``map<seed>/agent_models``, written by ``train.py --mode
independent,comm,distance,full --map_seed <seed> --num_seeds 5``) is evaluated with
``evaluate.py``'s protocol (``analysis.pipeline.evaluate_experiment``: 1000 fixed test
episodes per seed, greedy and at ε = 0.05, the hand-written reference policies, the
interventions on the channels and the measures of Lowe et al.), and gives:

* each mode's success (mean over seeds, bootstrap CI over seeds);
* the four effects of ``EFFECTS`` (contrasts of the modes' success), each with a paired
  bootstrap 95 % interval (``analysis.stats.mode_contrasts``) and ``established`` when the
  interval excludes 0;
* the map's ``landmark_distance`` (``PROPERTY``, from the grid alone) and, over the maps,
  its Spearman correlation with each effect at ε = 0.05 with a bootstrap interval over maps;
* what the agents do with the channels (``behaviour``, ``panel_behaviour.py``): homing while
  the partner waits on the target, who arrives first and how long the pair takes to meet, the
  message on and off the target, the communication measures and the interventions.

Outputs beside the map folders (each file written atomically; an interrupted run leaves the
previous ones): ``panel.json``, ``panel.csv``, ``panel_effects.png`` (``panel_outputs.py``)
and ``timing.json`` (wall time per map: the only file that differs between identical reruns).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.baselines import int_list
from analysis.pipeline import CONDITIONS, evaluate_experiment
from analysis.runs import read_experiment
from analysis.stats import (
    BOOTSTRAP_RESAMPLES,
    CONFIDENCE,
    mode_contrasts,
    spearman_interval,
)
from batch.plumbing import ProgressLine, run_jobs
from rollout import EVAL_EPSILON, EVAL_SEED
from settings import available_cores
from vector_env import DEFAULT_MAP_SEED, OBSTACLE, TARGET

from studies.multiplicity import panel_effects
from studies.panel_behaviour import BEHAVIOUR, beacon_behaviour, mode_behaviour, seed_behaviour
from studies.panel_outputs import format_table, panel_summary, plot_effects, write_csv
from studies.staging import run_command

PANEL_DIR = Path(__file__).resolve().parent.parent / "results" / "studies" / "panel"
PANEL_MAP_SEEDS = (DEFAULT_MAP_SEED, *range(11))
MAP_RULE = (
    "the assignment's map (map seed 641) and the generator's first 11 map seeds, 0-10, "
    "fixed before any result; every map trained with the main experiment's recipe"
)
EFFECTS = {
    "message": {"comm": 1.0, "independent": -1.0},
    "distance": {"distance": 1.0, "independent": -1.0},
    "both": {"full": 1.0, "independent": -1.0},
    "interaction": {"full": 1.0, "comm": -1.0, "distance": -1.0, "independent": 1.0},
}
EFFECT_WORDS = {
    "message": "comm - independent: what the partner's message adds to the patch",
    "distance": "distance - independent: what the distance to the partner adds to the patch",
    "both": "full - independent: what message and distance together add",
    "interaction": "full - comm - distance + independent: what the two add together beyond "
    "the sum of what each adds alone",
}
PROPERTY = {
    "name": "landmark_distance",
    "definition": "the smallest Chebyshev distance from the target to an obstacle or an "
    "off-grid cell, minus 1: 0 when the target's own 3 × 3 patch shows a wall or an obstacle "
    "(a corner target gives 0), larger the farther the target lies in open ground",
}


def landmark_distance(grid: np.ndarray) -> int:
    """``PROPERTY``: the smallest Chebyshev distance from the target to an obstacle or an
    off-grid cell, minus 1 (grid (H, W): 0 free, 1 obstacle, 2 target)."""
    grid = np.asarray(grid)
    row, col = np.argwhere(grid == TARGET)[0]
    rows, cols = grid.shape
    nearest = min(row, col, rows - 1 - row, cols - 1 - col) + 1  # the first off-grid ring
    obstacles = np.argwhere(grid == OBSTACLE)
    if len(obstacles):
        nearest = min(nearest, int(np.abs(obstacles - (row, col)).max(axis=1).min()))
    return int(nearest) - 1


def map_effects(successes: dict[str, dict[str, np.ndarray]]) -> dict[str, dict]:
    """Per condition, every effect of ``EFFECTS`` whose modes were trained, with its paired
    interval, ``established`` and a ``verdict`` (gain, loss or unclear)."""
    effects = {}
    for condition in CONDITIONS:
        contrasts = {
            name: coefficients
            for name, coefficients in EFFECTS.items()
            if set(coefficients) <= set(successes)
        }
        per_mode = {mode: s[condition] for mode, s in successes.items()}
        entries = mode_contrasts(per_mode, contrasts)
        for entry in entries.values():
            entry["verdict"] = (
                ("gain" if entry["mean"] > 0 else "loss") if entry["established"] else "unclear"
            )
        effects[condition] = entries
    return effects


def evaluate_map(
    map_seed: int, models_dir: str, num_episodes: int, progress: Any = None
) -> tuple[dict, float]:
    """The panel's entry of one map and the seconds it took (a ``batch.plumbing.run_jobs`` job)."""
    torch.set_num_threads(1)  # batches of ~1000 rows: one thread, and the two workers apart
    start = time.perf_counter()
    experiment = read_experiment(f"panel/map{map_seed}", Path(models_dir))
    outcome = evaluate_experiment(experiment, num_episodes, EVAL_EPSILON, seed_behaviour)
    performance, communication = outcome.performance, outcome.communication
    modes = list(experiment.seeds)
    effects = map_effects(outcome.successes)
    references = {}
    for name, summary in performance["baselines"].items():
        references[name] = {k: summary[k] for k in ("success_rate", "mean_steps_to_success")}
        if "eps" in summary:
            references[name]["eps"] = {
                k: summary["eps"][k] for k in ("success_rate", "mean_steps_to_success")
            }
    entry = {
        "map_seed": map_seed,
        "target": performance["target"],
        PROPERTY["name"]: landmark_distance(experiment.grid),
        "grid": performance["grid"],
        "seeds": experiment.seeds,
        "success": {
            mode: {c: performance["modes"][mode][c]["success_rate"] for c in CONDITIONS}
            for mode in modes
        },
        "steps_to_success": {
            mode: {c: performance["modes"][mode][c]["mean_steps_to_success"] for c in CONDITIONS}
            for mode in modes
        },
        "effects": effects,
        "channel_effect_established": any(e["established"] for e in effects["eps"].values()),
        "references": references,
        "behaviour": {
            "modes": {
                mode: mode_behaviour(performance["modes"][mode], communication["modes"][mode])
                for mode in modes
            },
            "beacon_explorer": beacon_behaviour(experiment, num_episodes),
        },
    }
    return entry, time.perf_counter() - start


def check_panel(panel_dir: Path, maps: list[int]) -> dict[int, Path]:
    """The agent_models folder of every map, each checked (manifest, files, map seed,
    modes); ValueError naming the folder and what is wrong, before any evaluation."""
    folders = {}
    for map_seed in maps:
        models_dir = panel_dir / f"map{map_seed}" / "agent_models"
        if not models_dir.is_dir():
            raise ValueError(
                f"{models_dir}: no such folder; train the map first (train.py --mode "
                f"independent,comm,distance,full --map_seed {map_seed} --num_seeds 5 "
                f"--output_dir {panel_dir / f'map{map_seed}'})"
            )
        experiment = read_experiment(f"panel/map{map_seed}", models_dir)
        if experiment is None or experiment.manifest is None:
            raise ValueError(f"{models_dir}: no manifest.json of a train.py batch")
        if int(experiment.settings["map_seed"]) != map_seed:
            raise ValueError(
                f"{models_dir}: trained on map seed {experiment.settings['map_seed']}, "
                f"not {map_seed}"
            )
        if "independent" not in experiment.seeds or len(experiment.seeds) < 2:
            raise ValueError(
                f"{models_dir}: has modes {sorted(experiment.seeds)}; the effects need "
                "independent and at least one of comm, distance, full"
            )
        folders[map_seed] = models_dir
    return folders


def correlations(maps: dict[str, dict]) -> dict[str, dict]:
    """Spearman's rho of ``PROPERTY`` with each effect at ε over the maps that have it."""
    result = {}
    for name in EFFECTS:
        having = [m for m in maps.values() if name in m["effects"]["eps"]]
        if len(having) >= 2:
            result[name] = spearman_interval(
                [m[PROPERTY["name"]] for m in having],
                [m["effects"]["eps"][name]["mean"] for m in having],
            ) | {"maps": [m["map_seed"] for m in having]}
    return result


def summarise(entries: list[dict], num_episodes: int) -> dict[str, Any]:
    """The study's JSON (no wall times): protocol, the maps, correlations, counts."""
    maps = {str(e["map_seed"]): e for e in entries}
    protocol = {
        "map_rule": MAP_RULE,
        "map_seeds": [e["map_seed"] for e in entries],
        "evaluation_seed": EVAL_SEED,
        "episodes_per_seed": num_episodes,
        "conditions": {"greedy": 0.0, "eps": EVAL_EPSILON},
        "success": "both agents on the target on the same step within max_steps",
        "bootstrap_resamples": BOOTSTRAP_RESAMPLES,
        "confidence": CONFIDENCE,
        "effects": {n: {"coefficients": EFFECTS[n], "meaning": EFFECT_WORDS[n]} for n in EFFECTS},
        "effect_interval": "percentile bootstrap; each resample redraws the test episodes "
        "once for all modes and seeds (paired) and, independently in each mode, its training "
        "seeds; established: the interval excludes 0",
        "property": PROPERTY,
        "correlation": "Spearman's rho (average ranks for ties) of the property with each "
        "effect at eps over the maps; 95 % percentile bootstrap over maps (maps redrawn with "
        "replacement); resamples in which the property or the effect is constant have no "
        "correlation and are left out (undefined_resamples)",
        "behaviour": BEHAVIOUR,
    }
    results = {"protocol": protocol, "maps": maps, "correlations": correlations(maps)}
    return results | {"summary": panel_summary(results)}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description=__doc__.split("\n\n")[0],
        epilog="Relative paths are resolved against the current folder.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add = parser.add_argument
    add(
        "--panel_dir",
        "--panel-dir",
        type=Path,
        default=PANEL_DIR,
        help="folder holding map<seed>/agent_models; the outputs are written there",
    )
    add(
        "--maps",
        type=int_list,
        default=list(PANEL_MAP_SEEDS),
        help="map seeds, comma-separated, e.g. 641,4 (default: the panel's rule)",
    )
    add(
        "--num_episodes",
        "--num-episodes",
        type=int,
        default=1000,
        help="test episodes per trained seed and condition (1..5000)",
    )
    add(
        "--workers",
        type=int,
        default=min(2, available_cores()),
        help="processes evaluating maps in parallel (1..64)",
    )
    args = parser.parse_args(argv)
    if not args.maps or min(args.maps) < 0 or len(set(args.maps)) != len(args.maps):
        parser.error(f"--maps must be distinct non-negative integers, got {args.maps}")
    if not 1 <= args.num_episodes <= 5000:
        parser.error(f"--num_episodes must be an integer in 1..5000, got {args.num_episodes}")
    if not 1 <= args.workers <= 64:
        parser.error(f"--workers must be an integer in 1..64, got {args.workers}")
    if not args.panel_dir.is_dir():
        parser.error(f"--panel_dir {args.panel_dir}: no such folder")
    try:
        args.folders = check_panel(args.panel_dir, args.maps)
    except (FileNotFoundError, ValueError) as error:
        parser.error(str(error))
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Evaluate every map of the panel and write the study's files."""
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    args = parse_args(argv)
    jobs = [(m, str(folder), args.num_episodes) for m, folder in args.folders.items()]
    done = run_jobs(evaluate_map, jobs, args.workers, ProgressLine(len(jobs), 0))
    results = summarise([entry for entry, _ in done], args.num_episodes)
    write_json_atomic(args.panel_dir / "panel.json", results)
    write_csv(args.panel_dir / "panel.csv", results)
    plot_effects(args.panel_dir / "panel_effects.png", results, panel_effects(results)["maps"])
    timing = {
        f"map{m}": round(seconds, 1) for (m, _, _), (_, seconds) in zip(jobs, done, strict=True)
    }
    write_json_atomic(args.panel_dir / "timing.json", {"seconds_per_map": timing})
    print(format_table(results))
    print(f"wrote {args.panel_dir} (seconds per map: {timing})")
    return results


if __name__ == "__main__":
    run_command(main)
