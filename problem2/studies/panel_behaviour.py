"""What the agents of the map panel (``studies/panel.py``) do with the channels, from the
recorded test episodes of each seed: homing while the partner waits on the target (by
shortest path, ``analysis.arrivals.homing_counts``), who reaches the target first and how long
the pair then takes to meet (``analysis.arrivals.arrivals``), beside the beacon explorer's;
and, from the evaluated entries, the message on and off the target, the measures of Lowe et
al. and the interventions."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from analysis.arrivals import arrivals, homing_counts, homing_shares
from analysis.baselines import POLICIES
from analysis.episodes import target_distances
from analysis.evaluator import MultiAgentEvaluator, experiment_evaluator
from analysis.pipeline import CONDITIONS
from analysis.runs import Experiment
from analysis.stats import seed_statistics
from rollout import EVAL_EPSILON, EVAL_SEED, EpisodeResults

BEHAVIOUR = {
    "homing": "moves made while the partner stood on the target and the agent did not: "
    "closer, farther or neither by the shortest-path distance to the target; counts summed "
    "over seeds and both agents",
    "arrivals": "per seed (stats over seeds): share of episodes in which an agent reached "
    "the target; among those, the share in which A, B or both at once arrived first; the "
    "step of the first arrival; in successful episodes, the steps from the first arrival to "
    "the meeting",
    "message": "mean message sent while the sender stands on the target and while it does "
    "not (greedy test episodes, mean of the two agents; stats over seeds)",
    "communication_measures": "Lowe et al. (2019), message cut in 2 bins, greedy test "
    "episodes (analysis.information), stats over seeds",
    "interventions": "success with a channel replaced minus with the real one "
    "(analysis.interventions), stats over seeds, and the verdict",
}


def arrival_measures(results: EpisodeResults, target: tuple[int, int]) -> dict[str, float | None]:
    """Who reaches the target first and how long the pair then takes to meet, for recorded
    episodes (see ``BEHAVIOUR["arrivals"]``); None where no episode qualifies."""
    positions = results.trajectories["positions"]  # (E, T + 1, 2, 2)
    arrived = arrivals(positions, results.lengths, target)
    first = np.where(arrived.reached, arrived.first_arrival, positions.shape[1])  # (E, 2)
    any_arrival = arrived.reached.any(axis=1)
    earliest = first.min(axis=1)
    count = int(any_arrival.sum())

    def share(mask: np.ndarray) -> float | None:
        return float((mask & any_arrival).sum() / count) if count else None

    met = results.successes
    return {
        "episodes_with_an_arrival": float(any_arrival.mean()),
        "A_first": share(first[:, 0] < first[:, 1]),
        "B_first": share(first[:, 1] < first[:, 0]),
        "both_at_once": share(first[:, 0] == first[:, 1]),
        "first_arrival_step": float(earliest[any_arrival].mean()) if count else None,
        "steps_first_arrival_to_meeting": (
            float((results.lengths - earliest)[met].mean()) if met.any() else None
        ),
    }


def seed_behaviour(
    evaluator: MultiAgentEvaluator, runs: dict[str, EpisodeResults]
) -> dict[str, dict]:
    """Homing counts and arrival measures of one seed's (or policy's) recorded episodes, per
    condition of ``runs``."""
    distances = target_distances(evaluator.setting.grid)
    target = evaluator.setting.target
    return {
        condition: {"homing_counts": homing_counts(results, distances).tolist()}
        | arrival_measures(results, target)
        for condition, results in runs.items()
    }


def pooled_behaviour(per_seed: list[dict[str, dict]]) -> dict[str, dict]:
    """Per condition: homing counts summed over seeds with their shares, and each arrival
    measure as seed statistics."""
    pooled = {}
    for condition in per_seed[0]:
        entries = [seed[condition] for seed in per_seed]
        counts = np.sum([e["homing_counts"] for e in entries], axis=0).tolist()
        measures = [k for k in entries[0] if k != "homing_counts"]
        pooled[condition] = {
            "homing": {"counts": counts, "shares": homing_shares(counts)},
            "arrivals": {k: seed_statistics([e[k] for e in entries]) for k in measures},
        }
    return pooled


def message_on_off(per_seed_communication: dict[str, dict]) -> dict[str, dict]:
    """Mean message on and off the target (stats over seeds, each seed the mean of its two
    agents), from ``analysis.messages.message_correlations`` of the greedy episodes."""
    result = {}
    for key, name in (("mean_if_true", "on_target"), ("mean_if_false", "off_target")):
        values = []
        for seed in per_seed_communication.values():
            agents = [a["on_target"][key] for a in seed["correlations"].values()]
            present = [v for v in agents if v is not None]
            values.append(float(np.mean(present)) if present else None)
        result[name] = seed_statistics(values)
    return result


def beacon_behaviour(experiment: Experiment, num_episodes: int) -> dict[str, dict]:
    """:func:`seed_behaviour` of the beacon explorer's greedy test episodes on the map."""
    factory = partial(POLICIES["beacon_explorer"], seed=EVAL_SEED)
    evaluator = experiment_evaluator(experiment, EVAL_EPSILON, policy_factory=factory)
    behaviour = seed_behaviour(evaluator, {"greedy": evaluator.run(num_episodes)})
    return pooled_behaviour([behaviour])


def mode_behaviour(performance: dict, communication: dict) -> dict[str, Any]:
    """What one mode's agents do with the channels, from its evaluated entries."""
    measures = [seed["measures"] for seed in performance["per_seed"].values()]
    entry = pooled_behaviour(measures)
    entry["message"] = message_on_off(communication["per_seed"])
    entry["communication_measures"] = communication["measures"]["K2"]
    tests = communication.get("interventions", {})
    entry["interventions"] = {
        channel: {
            condition: {k: test[condition][k] for k in ("delta_success", "verdict")}
            | {"raising": test[condition]["raising_interventions"]}
            for condition in CONDITIONS
        }
        for channel, test in tests.items()
    }
    return entry
