"""What ``python evaluate.py`` does: evaluate every trained (mode, seed) of every experiment
found, aggregate over seeds, test the message causally, test the main models on unseen
maps, and write the JSON files, the Markdown table and the figures.

Aggregates over training seeds are ``analysis_stats.seed_statistics`` dicts: ``mean``,
``ci95`` (percentile bootstrap over seeds, 10 000 resamples), ``iqm``, ``n``, ``per_seed``.
Within one seed the causal differences carry an episode-level paired bootstrap CI.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import torch
from analysis_episodes import episode_summary
from analysis_evaluator import GENERALIZATION_MAP_SEEDS, MultiAgentEvaluator
from analysis_failures import (
    DECOMPOSITION,
    FAILURE_DEFINITIONS,
    FAILURE_KINDS,
    failure_decomposition,
)
from analysis_information import MEASURES, communication_measures
from analysis_interventions import (
    CHANNEL_INTERVENTIONS,
    CHANNEL_MODES,
    INTERVENTIONS,
    VERDICTS,
    channel_verdict,
    legacy_message_test,
    mean_received,
    raising,
)
from analysis_messages import (
    FEATURE_DESCRIPTIONS,
    message_correlations,
    message_distribution,
)
from analysis_runs import (
    Experiment,
    best_seed,
    load_model_pair,
    model_paths,
    relative_models_dir,
)
from analysis_stats import BOOTSTRAP_RESAMPLES, seed_statistics
from baselines import POLICIES
from grid_maps import generate_map
from multi_agent_env import MultiAgentEnv
from rollout import EVAL_SEED, EpisodeResults, summarize

CONDITIONS = ("greedy", "eps")
MESSAGE_TEST = {
    "real": "the partner's message as sent",
    "shuffled": "intervention same_step: the message another episode received at the same step",
    "zeroed": "intervention constant_0: the message 0 at every step",
}


@dataclass
class ExperimentOutcome:
    """Everything evaluated for one experiment; ``runs`` keeps the recorded episodes of each
    mode's best seed, for the figures."""

    performance: dict
    communication: dict
    runs: dict[str, dict[str, EpisodeResults]] = field(default_factory=dict)


def _evaluator(
    experiment: Experiment, epsilon: float, mode: str | None = None, seed: int | None = None, **kw
) -> MultiAgentEvaluator:
    settings = experiment.settings
    # Returns are reported under the assignment's reward (the env's default), whatever
    # reward the agents were trained on; success does not depend on the reward.
    env = MultiAgentEnv(grid=experiment.grid, max_steps=int(settings["max_steps"]))
    if mode is None:
        return MultiAgentEvaluator(env, epsilon=epsilon, **kw)
    models = load_model_pair(experiment.models_dir, mode, seed)
    names = tuple(str(path) for path in model_paths(experiment.models_dir, mode, seed))
    return MultiAgentEvaluator(env, *models, epsilon=epsilon, names=names, **kw)


def aggregate(summaries: list[dict]) -> dict[str, Any]:
    """Seed statistics of success, steps, return and failure shares (one summary a seed)."""
    result: dict[str, Any] = {
        "epsilon": summaries[0]["epsilon"],
        "episodes_per_seed": summaries[0]["episodes"],
    }
    for key in ("success_rate", "mean_steps_to_success", "mean_return"):
        result[key] = seed_statistics([s[key] for s in summaries])
    result["failures"] = {
        kind: seed_statistics([s["failures"][kind] for s in summaries]) for kind in FAILURE_KINDS
    }
    result["failure_decomposition"] = {
        key: seed_statistics([s["failure_decomposition"][key] for s in summaries])
        for key in DECOMPOSITION
    }
    return result


def _intervention_tests(
    evaluators: dict[int, MultiAgentEvaluator],
    real: dict[int, dict[str, EpisodeResults]],
    mode: str,
    num_episodes: int,
) -> dict[str, Any]:
    """Success under every intervention on each channel the mode reads (one batch per
    seed, :meth:`MultiAgentEvaluator.intervention_test`; ``constant_mean`` is the mode's
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
        seed: evaluator.intervention_test(num_episodes, real[seed], channels, constants, seed)
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


def evaluate_mode(
    experiment: Experiment, mode: str, num_episodes: int, epsilon: float
) -> tuple[dict, dict, dict[str, EpisodeResults]]:
    """Performance and communication entries of one mode, and the best seed's episodes."""
    per_seed_perf, per_seed_comm, seed_runs, evaluators = {}, {}, {}, {}
    target = tuple(int(v) for v in np.argwhere(experiment.grid == 2)[0])
    for seed in experiment.seeds[mode]:
        evaluator = evaluators[seed] = _evaluator(experiment, epsilon, mode, seed)
        runs = seed_runs[seed] = evaluator.run_conditions(num_episodes)
        per_seed_perf[str(seed)] = {
            name: episode_summary(runs[name], target, evaluator.conditions[name])
            | {"failure_decomposition": failure_decomposition(runs[name], target)}
            for name in CONDITIONS
        }
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
    communication: dict[str, Any] = {"label": experiment.label(mode), "per_seed": per_seed_comm}
    communication["measures"] = aggregate_measures([c["measures"] for c in per_seed_comm.values()])
    tests = _intervention_tests(evaluators, seed_runs, mode, num_episodes)
    if tests:
        communication["interventions"] = tests
    if "message" in tests:
        communication["causal"] = legacy_message_test(tests["message"], epsilon)
    return performance, communication, seed_runs[chosen]


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
    experiment: Experiment, num_episodes: int, epsilon: float
) -> ExperimentOutcome:
    """Every mode and seed of ``experiment`` beside the baseline policies (greedy)."""
    baselines = {}
    for name, policy in POLICIES.items():
        factory = partial(lambda grid, make: make(grid, EVAL_SEED), make=policy)
        evaluator = _evaluator(experiment, epsilon, policy_factory=factory)
        results = evaluator.run(num_episodes)
        baselines[name] = episode_summary(results, evaluator.setting.target, 0.0)
    settings = experiment.settings
    info = {
        key: settings.get(key) for key in ("map_seed", "reward_mode", "comm_learning", "max_steps")
    }
    info |= {"models_dir": relative_models_dir(experiment.name), "grid": experiment.grid.tolist()}
    info["manifest"] = experiment.manifest is not None
    info["target"] = [int(v) for v in np.argwhere(experiment.grid == 2)[0]]
    outcome = ExperimentOutcome(
        performance={**info, "baselines": baselines, "modes": {}},
        communication={"map_seed": info["map_seed"], "modes": {}},
    )
    for mode in experiment.seeds:
        performance, communication, runs = evaluate_mode(experiment, mode, num_episodes, epsilon)
        outcome.performance["modes"][mode] = performance
        outcome.communication["modes"][mode] = communication
        outcome.runs[mode] = runs
    return outcome


def evaluate_generalization(experiment: Experiment, num_episodes: int, epsilon: float) -> dict:
    """Every model pair of ``experiment`` on map seeds 0–9, beside the baseline policies on
    each map; per map and mode, seed statistics of the success rate."""
    size = experiment.grid.shape
    maps: dict[str, dict] = {}
    for map_seed in GENERALIZATION_MAP_SEEDS:
        grid = generate_map(size, map_seed)
        entry: dict[str, Any] = {"target": [int(v) for v in np.argwhere(grid == 2)[0]]}
        for name, policy in POLICIES.items():
            factory = partial(lambda g, make: make(g, EVAL_SEED), make=policy)
            evaluator = MultiAgentEvaluator(
                MultiAgentEnv(grid=grid, max_steps=int(experiment.settings["max_steps"])),
                policy_factory=factory,
            )
            entry[name] = summarize(evaluator.run(num_episodes, record=False))
        entry["modes"] = {}
        maps[str(map_seed)] = entry
    summary: dict[str, dict] = {}
    for mode, seeds in experiment.seeds.items():
        per_seed = [
            _evaluator(experiment, epsilon, mode, seed).test_generalization(
                len(GENERALIZATION_MAP_SEEDS), num_episodes, oracle=False
            )
            for seed in seeds
        ]
        for map_seed, entry in maps.items():
            entry["modes"][mode] = {
                name: seed_statistics([run["maps"][map_seed][name] for run in per_seed])
                for name in CONDITIONS
            }
        summary[mode] = {
            name: seed_statistics([run[f"mean_{name}"] for run in per_seed]) for name in CONDITIONS
        }
    return {
        "trained_map_seed": experiment.settings["map_seed"],
        "episodes_per_map": num_episodes,
        "epsilon": epsilon,
        "map_seeds": list(GENERALIZATION_MAP_SEEDS),
        "maps": maps,
        "mean_over_maps": summary,
        "baselines_mean_over_maps": {
            name: float(np.mean([entry[name]["success_rate"] for entry in maps.values()]))
            for name in POLICIES
        },
    }


HELD_OUT_MAP_SEEDS = tuple(range(1000, 1040))  # maps no model or setting was chosen on


def evaluate_held_out_baselines(size: tuple[int, int], max_steps: int, num_episodes: int) -> dict:
    """Every baseline policy (greedy) on ``HELD_OUT_MAP_SEEDS``: success per map and its
    mean over maps with a 95 % bootstrap CI over maps. What needs no learning, off the
    training map."""
    per_map: dict[str, list[float]] = {name: [] for name in POLICIES}
    for map_seed in HELD_OUT_MAP_SEEDS:
        env = MultiAgentEnv(grid=generate_map(size, map_seed), max_steps=max_steps)
        for name, policy in POLICIES.items():
            factory = partial(
                lambda g, make, seed: make(g, seed), make=policy, seed=EVAL_SEED + map_seed
            )
            results = MultiAgentEvaluator(env, policy_factory=factory).run(
                num_episodes, record=False
            )
            per_map[name].append(float(results.successes.mean()))
    return {
        "map_seeds": list(HELD_OUT_MAP_SEEDS),
        "episodes_per_map": num_episodes,
        "success_rate": {name: seed_statistics(rates) for name, rates in per_map.items()},
        "note": "ci95 and per_seed are over maps here",
    }


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
        "success": "both agents on the target on the same step within max_steps",
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
        results["generalization"]["held_out"] = evaluate_held_out_baselines(
            main.grid.shape, int(main.settings["max_steps"]), args.generalization_episodes
        )
        print(f"evaluated generalisation ({time.perf_counter() - start:.0f} s)")
    return results, outcomes
