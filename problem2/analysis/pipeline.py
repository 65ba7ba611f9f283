"""The report's evaluation of the trained agents (``python -m analysis.pipeline``, run by
``make p2-evaluate``): every trained (mode, seed) of every experiment found (the main one and
the studies beside it), aggregated over seeds, the modes compared pairwise, every input
channel tested causally, the baselines beside them, and the main models tested on unseen and
held-out maps (``analysis/generalization.py``); ``analysis/outputs.py`` writes every file of
``evaluation_results/``.

    python -m analysis.pipeline                       # from problem2/, as make runs it
    python -m analysis.pipeline --checkpoint my_run   # a train.py --output_dir folder

It takes ``evaluate.py``'s flags and guarantees (bad flags and bad model files refused
before anything is written) and runs the same test episodes through the same
``MultiAgentEvaluator``: the three files ``python evaluate.py`` writes are written here in
full, every number of theirs at the same place.

Aggregates over training seeds are ``analysis.stats.seed_statistics`` dicts: ``mean``,
``ci95`` (percentile bootstrap over seeds, 10 000 resamples), ``iqm``, ``n``, ``per_seed``.
Within one seed the causal differences carry an episode-level paired bootstrap CI.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from safety import make_console_safe, use_reproducible_matmul

import numpy as np
import torch
from rollout import EVAL_SEED, EpisodeResults

from analysis.arrivals import DECOMPOSITION, failure_decomposition
from analysis.baselines import POLICIES
from analysis.console import generalization_summary, repository_path, success_summary
from analysis.episodes import SUCCESS, episode_summary
from analysis.evaluator import MultiAgentEvaluator, experiment_evaluator
from analysis.failures import FAILURE_DEFINITIONS, FAILURE_KINDS
from analysis.generalization import evaluate_generalization, evaluate_held_out
from analysis.information import MEASURES, communication_measures
from analysis.interventions import (
    CHANNEL_INTERVENTIONS,
    CHANNEL_MODES,
    INTERVENTIONS,
    VERDICTS,
    causal_message_test,
    channel_verdict,
    intervention_test,
    mean_received,
    raising,
)
from analysis.messages import (
    FEATURE_DESCRIPTIONS,
    message_correlations,
    message_distribution,
)
from analysis.outputs import write_outputs
from analysis.runs import (
    DEFAULT_CHECKPOINT,
    Experiment,
    best_seed,
    checked_args,
    experiment_info,
    make_parser,
    read_experiment,
)
from analysis.stats import BOOTSTRAP_RESAMPLES, mode_differences, seed_statistics

CONDITIONS = ("greedy", "eps")
MODE_DIFFERENCES = (
    "each pair of modes, keyed {later}_minus_{earlier} in the order independent, comm, full: "
    "success of the later minus the earlier (a mode's success is the mean over its seeds of "
    "each seed's success rate); ci95: percentile bootstrap, each resample redrawing the test "
    "episodes once for all modes and seeds (paired by episode set) and, independently in "
    "each mode, its training seeds; ci95_seeds_only: the same with the episode set held "
    "fixed; established: ci95 excludes 0"
)
MESSAGE_TEST = {
    "real": "the partner's message as sent",
    "shuffled": "intervention same_step: the message another episode received at the same step",
    "zeroed": "intervention constant_0: the message 0 at every step",
}


@dataclass
class ExperimentOutcome:
    """Everything evaluated for one experiment; ``runs`` keeps the recorded episodes of each
    mode's best seed, for the figures; ``successes[mode][condition]`` (seeds, E) the
    per-episode success of every seed, for contrasts between modes."""

    performance: dict
    communication: dict
    runs: dict[str, dict[str, EpisodeResults]] = field(default_factory=dict)
    successes: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


# Extra measures of one seed's recorded test episodes: (its evaluator, {condition: episodes})
# -> a JSON-ready dict, stored in the performance entry as per_seed[<seed>]["measures"].
SeedMeasures = Callable[[MultiAgentEvaluator, dict[str, EpisodeResults]], dict]


def aggregate(summaries: list[dict]) -> dict[str, Any]:
    """Seed statistics of success, steps, return and failure shares (one summary a seed)."""
    result: dict[str, Any] = {
        "epsilon": summaries[0]["epsilon"],
        "episodes_per_seed": summaries[0]["episodes"],
    }
    for key in ("success_rate", "mean_steps_to_success", "mean_return"):
        result[key] = seed_statistics([s[key] for s in summaries])
    result["failures"] = {
        kind: seed_statistics([s["failures"][kind] for s in summaries])
        | {"pooled": pooled_over_failures(summaries, "failures", kind)}
        for kind in FAILURE_KINDS
    }
    result["failure_decomposition"] = {}
    for key in DECOMPOSITION:
        stats = seed_statistics([s["failure_decomposition"][key] for s in summaries])
        if key in FAILED_EPISODE_KINDS:
            stats["pooled"] = pooled_over_failures(summaries, "failure_decomposition", key)
        result["failure_decomposition"][key] = stats
    return result


FAILED_EPISODE_KINDS = ("navigation", "timing", "reached_and_left")  # shares of failed episodes


def pooled_over_failures(summaries: list[dict], table: str, kind: str) -> float | None:
    """The share of ``kind`` among the failed episodes of every seed together (each seed's
    share weighted by its number of failed episodes); None if no seed failed."""
    failed = [s[table]["failed_episodes"] for s in summaries]
    shares = [s[table][kind] for s in summaries]
    total = sum(failed)
    if total == 0:
        return None
    return sum(n * share for n, share in zip(failed, shares, strict=True) if n) / total


def _intervention_tests(
    evaluators: dict[int, MultiAgentEvaluator],
    real: dict[int, dict[str, EpisodeResults]],
    mode: str,
    num_episodes: int,
) -> dict[str, Any]:
    """Success under every intervention on each channel the mode reads (one batch per
    seed, :func:`analysis.interventions.intervention_test`; ``constant_mean`` is the mode's
    mean received value over its seeds), Δsuccess (intervention − real, paired by episode
    and exploration draws) as seed statistics, and a verdict."""
    channels = tuple(c for c in CHANNEL_MODES if mode in CHANNEL_MODES[c])
    if not channels:
        return {}
    message_index = next(iter(evaluators.values())).setting.obs_window ** 2
    indices = {"message": message_index, "distance": message_index + 1}
    constants = {
        (channel, condition): mean_received([r[condition] for r in real.values()], indices[channel])
        for channel in channels
        for condition in CONDITIONS
    }
    rates = {
        seed: intervention_test(evaluator, num_episodes, real[seed], channels, constants, seed)
        for seed, evaluator in evaluators.items()
    }
    tests: dict[str, Any] = {}
    for channel in channels:
        kinds = CHANNEL_INTERVENTIONS[channel]
        entry: dict[str, Any] = {"observation_index": indices[channel]}
        for condition in CONDITIONS:
            per_seed = {s: rates[s][channel][condition] for s in rates}
            delta = {
                k: seed_statistics([r[k] - r["real"] for r in per_seed.values()]) for k in kinds[1:]
            }
            verdict = channel_verdict(delta)
            helps = raising(delta)
            text = VERDICTS[verdict] + (
                f"; success rises under {', '.join(helps)} (95 % CI above 0)" if helps else ""
            )
            entry[condition] = {
                "constant_mean_value": constants[channel, condition],
                "raising_interventions": helps,
                "success": {k: seed_statistics([r[k] for r in per_seed.values()]) for k in kinds},
                "delta_success": delta,
                "verdict": verdict,
                "verdict_text": text,
            }
        tests[channel] = entry
    return tests


def condition_summaries(
    evaluator: MultiAgentEvaluator, runs: dict[str, EpisodeResults]
) -> dict[str, dict]:
    """Per condition (greedy, ε) the episode summary of ``runs`` with its failure
    decomposition."""
    target = evaluator.setting.target
    return {
        name: summary | {"failure_decomposition": failure_decomposition(runs[name], target)}
        for name, summary in evaluator.summaries(runs).items()
    }


def last_weights_performance(
    experiment: Experiment, mode: str, seed: int, num_episodes: int, epsilon: float
) -> dict[str, dict] | None:
    """:func:`condition_summaries` of the weights run (``mode``, ``seed``) ended with, on the
    same test episodes as its selected weights; None where the manifest lists none (a run
    without ``keep_best``, or a folder without manifest)."""
    run = ((experiment.manifest or {}).get("runs") or {}).get(f"{mode}_seed{seed}") or {}
    if "last_weights" not in run:
        return None
    folder = Path(run["last_weights"]["models"]["A"]).parent  # as the manifest lists them
    evaluator = experiment_evaluator(
        experiment, epsilon, mode, seed, models_dir=experiment.models_dir / folder
    )
    return condition_summaries(evaluator, evaluator.run_conditions(num_episodes))


def evaluate_mode(
    experiment: Experiment,
    mode: str,
    num_episodes: int,
    epsilon: float,
    seed_measures: SeedMeasures | None = None,
) -> tuple[dict, dict, dict[str, EpisodeResults], dict[str, np.ndarray]]:
    """Performance and communication entries of one mode, the best seed's episodes, and
    per condition the per-episode successes of every seed (seeds, E), for the mode
    differences; ``seed_measures`` adds its measures of each seed (see ``SeedMeasures``)."""
    per_seed_perf, per_seed_comm, seed_runs, evaluators = {}, {}, {}, {}
    for seed in experiment.seeds[mode]:
        evaluator = evaluators[seed] = experiment_evaluator(experiment, epsilon, mode, seed)
        runs = seed_runs[seed] = evaluator.run_conditions(num_episodes)
        per_seed_perf[str(seed)] = condition_summaries(evaluator, runs)
        if seed_measures is not None:
            per_seed_perf[str(seed)]["measures"] = seed_measures(evaluator, runs)
        last = last_weights_performance(experiment, mode, seed, num_episodes, epsilon)
        if last is not None:
            per_seed_perf[str(seed)]["last_weights"] = last
        q_functions = tuple(
            (lambda obs, m=m: m(torch.from_numpy(obs))[0].detach().numpy())
            for m in (evaluator.model_A, evaluator.model_B)
        )
        per_seed_comm[str(seed)] = {
            "messages": message_distribution(runs["greedy"]),
            "correlations": message_correlations(runs["greedy"], experiment.grid),
            "measures": communication_measures(
                runs["greedy"], experiment.grid, q_functions, epsilon
            ),
        }
    chosen = best_seed(experiment, mode)
    if chosen is None:  # no best-pair files: take the best seed of this evaluation
        chosen = max(seed_runs, key=lambda s: per_seed_perf[str(s)]["eps"]["success_rate"])
    performance = {
        "label": experiment.label(mode),
        "seeds": experiment.seeds[mode],
        "best_seed": chosen,
        **{name: aggregate([p[name] for p in per_seed_perf.values()]) for name in CONDITIONS},
        "per_seed": per_seed_perf,
    }
    if all("last_weights" in p for p in per_seed_perf.values()):
        performance["last_weights"] = {
            name: aggregate([p["last_weights"][name] for p in per_seed_perf.values()])
            for name in CONDITIONS
        }
    communication: dict[str, Any] = {"label": experiment.label(mode), "per_seed": per_seed_comm}
    communication["measures"] = aggregate_measures([c["measures"] for c in per_seed_comm.values()])
    tests = _intervention_tests(evaluators, seed_runs, mode, num_episodes)
    if tests:
        communication["interventions"] = tests
    if "message" in tests:
        communication["causal"] = causal_message_test(tests["message"], epsilon)
    successes = {
        name: np.stack([runs[name].successes for runs in seed_runs.values()]) for name in CONDITIONS
    }
    return performance, communication, seed_runs[chosen], successes


def aggregate_measures(per_seed: list[dict]) -> dict[str, Any]:
    """Seed statistics of every communication measure, per bin count and sender."""
    first = per_seed[0]
    return {
        bins: {
            measure: {
                sender: seed_statistics([entry[bins][measure][sender] for entry in per_seed])
                for sender in first[bins][measure]
            }
            for measure in first[bins]
        }
        for bins in first
    }


def evaluate_experiment(
    experiment: Experiment,
    num_episodes: int,
    epsilon: float,
    seed_measures: SeedMeasures | None = None,
) -> ExperimentOutcome:
    """Every mode and seed of ``experiment`` beside the baseline policies (greedy; the
    oracle also under key ``eps`` at ``epsilon``, so that steps compare like with like);
    ``seed_measures``: extra measures of each seed (see ``SeedMeasures``)."""
    baselines = {}
    for name, policy in POLICIES.items():
        factory = partial(lambda grid, make: make(grid, EVAL_SEED), make=policy)
        evaluator = experiment_evaluator(experiment, epsilon, policy_factory=factory)
        results = evaluator.run(num_episodes)
        baselines[name] = episode_summary(results, evaluator.setting.target, 0.0)
        if name == "oracle":
            explored = evaluator.run(num_episodes, epsilon)
            baselines[name]["eps"] = episode_summary(explored, evaluator.setting.target, epsilon)
    info = experiment_info(experiment)
    outcome = ExperimentOutcome(
        performance={**info, "baselines": baselines, "modes": {}},
        communication={"map_seed": info["map_seed"], "modes": {}},
    )
    for mode in experiment.seeds:
        performance, communication, runs, outcome.successes[mode] = evaluate_mode(
            experiment, mode, num_episodes, epsilon, seed_measures
        )
        outcome.performance["modes"][mode] = performance
        outcome.communication["modes"][mode] = communication
        outcome.runs[mode] = runs
    outcome.performance["mode_differences"] = differences_by_pair(outcome.successes)
    return outcome


def differences_by_pair(successes: dict[str, dict[str, np.ndarray]]) -> dict[str, dict]:
    """``{"<later>_minus_<earlier>": {condition: difference}}`` for every pair of modes
    (``analysis.stats.mode_differences``: paired by test episodes, seeds resampled within
    each mode); empty with fewer than two modes."""
    by_condition = {
        name: mode_differences({mode: s[name] for mode, s in successes.items()})
        for name in CONDITIONS
    }
    pairs = by_condition[CONDITIONS[0]]
    return {pair: {name: by_condition[name][pair] for name in CONDITIONS} for pair in pairs}


def evaluate_all(
    experiments: list[Experiment], args: argparse.Namespace
) -> tuple[dict[str, Any], dict[str, ExperimentOutcome]]:
    """Evaluate ``experiments`` (the main one first) with the options of ``args``
    (``num_episodes``, ``epsilon``, ``generalization_episodes``); returns (results, outcomes)."""
    protocol = {
        "evaluation_seed": EVAL_SEED,
        "episodes_per_seed": args.num_episodes,
        "conditions": {"greedy": 0.0, "eps": args.epsilon},
        "bootstrap_resamples": BOOTSTRAP_RESAMPLES,
        "confidence": 0.95,
        "success": SUCCESS,
        "mode_differences": MODE_DIFFERENCES,
    }
    outcomes, start = {}, time.perf_counter()
    for experiment in experiments:
        outcomes[experiment.name] = evaluate_experiment(experiment, args.num_episodes, args.epsilon)
        print(f"evaluated {experiment.name} ({time.perf_counter() - start:.0f} s)")
    results: dict[str, Any] = {
        "performance": {
            "protocol": protocol
            | {"failure_definitions": FAILURE_DEFINITIONS, "failure_decomposition": DECOMPOSITION},
            "experiments": {name: o.performance for name, o in outcomes.items()},
        },
        "communication": {
            "protocol": protocol
            | {"message_conditions": MESSAGE_TEST, "features": FEATURE_DESCRIPTIONS}
            | {"interventions": INTERVENTIONS, "channel_interventions": CHANNEL_INTERVENTIONS}
            | {"verdicts": VERDICTS, "measures": MEASURES},
            "experiments": {name: o.communication for name, o in outcomes.items()},
        },
    }
    main = next((e for e in experiments if e.name == "main"), None)
    if main is not None:
        results["generalization"] = evaluate_generalization(
            main, args.generalization_episodes, args.epsilon
        )
        results["generalization"]["held_out"] = evaluate_held_out(
            main, args.generalization_episodes, args.epsilon
        )
        print(f"evaluated generalisation ({time.perf_counter() - start:.0f} s)")
    return results, outcomes


def study_model_dirs(checkpoint_dir: Path) -> list[tuple[str, Path]]:
    """(name, agent_models folder) of the main experiment (``checkpoint_dir`` itself) and
    of every study that may exist under ``<checkpoint_dir>/../studies``."""
    studies = checkpoint_dir.parent / "studies"
    candidates = [("main", checkpoint_dir), ("per_step", studies / "per_step" / "agent_models")]
    candidates.append(("no_dial", studies / "no_dial" / "agent_models"))
    return candidates


def discover_experiments(checkpoint_dir: Path = DEFAULT_CHECKPOINT) -> list[Experiment]:
    """Every experiment with model files: the main one in ``checkpoint_dir``, then the
    studies beside it (see :func:`study_model_dirs`); those without models are skipped."""
    experiments = []
    for name, models_dir in study_model_dirs(Path(checkpoint_dir)):
        if (experiment := read_experiment(name, models_dir)) is not None:
            experiments.append(experiment)
    return experiments


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = make_parser(__doc__.split("\n\n")[0], prog="python -m analysis.pipeline")
    parser.add_argument(
        "--generalization_episodes",
        "--generalization-episodes",
        type=int,
        default=500,
        help="test episodes per model and map, generalisation test",
    )
    return checked_args(parser, argv)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Evaluate every experiment found from the checkpoint folder and write every output.
    A missing, damaged or unlisted model file ends the run (exit status 1) naming it,
    before anything is written: the manifests' checksums are checked when the experiments
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
                    f"note: no manifest.json in {repository_path(experiment.models_dir)}: "
                    "evaluating the model files found there"
                )
        results, outcomes = evaluate_all(experiments, args)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(f"python -m analysis.pipeline: error: {error}") from error
    output_dir = args.output_dir or args.checkpoint.parent / "evaluation_results"
    written = write_outputs(results, outcomes, output_dir)
    for line in success_summary(results["performance"]):
        print(line)
    for line in generalization_summary(results.get("generalization")):
        print(line)
    print(f"wrote {len(written)} files to {repository_path(output_dir)}")
    print(f"tables: {repository_path(output_dir / 'comparison_table.md')}")
    return results


if __name__ == "__main__":
    main()
