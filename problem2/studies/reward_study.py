"""Which reward to train on, argued from evidence under the assignment's own reward.

    python reward_study.py                  # exact DP on map 641 + both trained batches
    python reward_study.py --dp_only        # the exact DP table alone (seconds)
    python reward_study.py --plot_only      # redraw reward_study.png from reward_study.json
    python reward_study.py --per_step_models DIR --arrival_models DIR --output_dir DIR

1. Exact answer (``joint_dp.py``): the optimal joint policy with full information under the
   assignment's reward (``per_step``) and under the ``arrival`` reward, with the 50-step
   clock in the state (``finite_horizon``) and without it (``stationary``, what the trainer
   optimises: it bootstraps through the cut-off and the agents do not see time).
2. What learning does: every trained seed of two batches (trained with ``--reward_mode
   per_step`` and ``--reward_mode arrival``) on the same 1000 test episodes (seed
   ``rollout.EVAL_SEED``), greedy and ε-greedy. Returns under both rewards are computed from
   the recorded positions by ``joint_dp.returns_from_positions``, not taken from the env.
3. The verdict: literal-trained agents earning more assignment-reward return while
   succeeding less means the literal reward is misspecified for the goal.

Writes ``reward_study.json`` and ``reward_study.png`` into ``--output_dir``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from safety import use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.arrivals import arrivals
from analysis.episodes import target_distances
from analysis.evaluator import MultiAgentEvaluator
from analysis.runs import Experiment, load_model_pair, read_experiment
from analysis.stats import seed_statistics
from rollout import EVAL_EPSILON, EVAL_SEED
from settings import MODES
from vector_env import DEFAULT_MAP_SEED, TARGET, VectorMultiAgentEnv, generate_map

from studies import joint_dp
from studies.reward_study_outputs import CONDITIONS, format_table, plot_study
from studies.staging import run_command

STUDY_DIR = Path(__file__).resolve().parent.parent / "results" / "studies" / "reward"
MEASURES = {
    "success_rate": "share of episodes with both agents on the target within 50 steps",
    "mean_steps_to_success": "mean steps of the successful episodes (null if none)",
    "return_assignment": "mean undiscounted episode return under the assignment's reward "
    "(per_step: +10 both on target, +2 per step with exactly one on it, -0.1 otherwise)",
    "return_arrival": "mean undiscounted episode return under the arrival reward "
    "(+10 both on target, +2 on an agent's first arrival, -0.1 otherwise)",
    "one_never_arrives": "share of episodes in which one agent reaches the target and the "
    "other never does",
    "second_agent_reaches_target": "share of episodes in which both agents stand on the "
    "target at some step (not necessarily the same one)",
    "turned_away": "share of episodes with a step on which one agent stays on the target "
    "while the other moves from a cell next to the target (path distance 1) to a farther one",
    "time_between_arrivals": "mean steps from the first agent's first arrival to the "
    "second's, over episodes in which both arrive (null if none)",
    "steps_one_on_target": "mean number of steps per episode with exactly one agent on the "
    "target (the steps the assignment's reward pays +2 for)",
}


def episode_measures(
    positions: np.ndarray, lengths: np.ndarray, successes: np.ndarray, grid: np.ndarray
) -> dict[str, float | None]:
    """Every measure of ``MEASURES`` over recorded episodes: positions (E, T + 1, 2, 2)
    held after the end, lengths (E,), successes (E,)."""
    target = tuple(int(i) for i in np.argwhere(grid == TARGET)[0])
    arrived = arrivals(positions, lengths, target)
    both_arrived = arrived.both_arrived
    gaps = np.abs(arrived.first_arrival[:, 0] - arrived.first_arrival[:, 1])[both_arrived]
    distance = target_distances(grid)[positions[..., 0], positions[..., 1]]  # (E, T + 1, 2)
    within = np.arange(positions.shape[1])[None, :] <= lengths[:, None]  # (E, T + 1)
    stays = arrived.on[:, :-1] & arrived.on[:, 1:]  # (E, T, 2)
    leaves = (distance[:, :-1] == 1) & (distance[:, 1:] > 1) & within[:, 1:, None]
    turned_away = (stays & leaves[..., ::-1]).any(axis=(1, 2))

    def returns(reward: str) -> float:
        return float(joint_dp.returns_from_positions(positions, lengths, target, reward).mean())

    return {
        "success_rate": float(successes.mean()),
        "mean_steps_to_success": float(lengths[successes].mean()) if successes.any() else None,
        "return_assignment": returns("per_step"),
        "return_arrival": returns("arrival"),
        "one_never_arrives": float(arrived.one_never_arrives.mean()),
        "second_agent_reaches_target": float(both_arrived.mean()),
        "turned_away": float(turned_away.mean()),
        "time_between_arrivals": float(gaps.mean()) if gaps.size else None,
        "steps_one_on_target": float(arrived.steps_one_on_target.mean()),
    }


def exact_dp(grid: np.ndarray, gamma: float, horizon: int) -> dict:
    """Optimal values and the greedy optimal policy's behaviour from every start pair."""
    space = joint_dp.build_joint_space(grid)
    starts = space.start_states()
    cell_a, cell_b, _, _ = space.decode(starts)
    distance = target_distances(grid)[space.cells[:, 0], space.cells[:, 1]]
    table: dict = {
        "gamma": gamma,
        "horizon": horizon,
        "start_pairs": len(starts),
        "fastest_success_steps": float(np.maximum(distance[cell_a], distance[cell_b]).mean()),
    }
    for problem in ("finite_horizon", "stationary"):
        table[problem] = {}
        for reward in joint_dp.REWARDS:
            transitions = joint_dp.build_transitions(space, reward)
            if problem == "finite_horizon":
                solution = joint_dp.solve_finite_horizon(transitions, gamma, horizon)
            else:
                solution = joint_dp.solve_stationary(transitions, gamma)
            values = joint_dp.optimal_values(solution, starts)
            episodes = joint_dp.roll_out(space, transitions, solution, starts, horizon)
            table[problem][reward] = {
                "optimal_value": {
                    "mean": float(values.mean()),
                    "min": float(values.min()),
                    "max": float(values.max()),
                },
                **episode_measures(episodes.positions, episodes.lengths, episodes.successes, grid),
            }
    clock, no_clock = table["finite_horizon"], table["stationary"]
    arrival_steps = clock["arrival"]["mean_steps_to_success"]  # None if it never succeeds
    table["what_each_reward_asks_for"] = {
        "assignment_optimum_with_clock_succeeds_only_on_last_step": bool(
            clock["per_step"]["mean_steps_to_success"] == horizon
        ),
        "assignment_optimum_without_clock_success_rate": no_clock["per_step"]["success_rate"],
        "arrival_optimum_success_rate": min(
            clock["arrival"]["success_rate"], no_clock["arrival"]["success_rate"]
        ),
        "arrival_optimum_extra_steps_over_fastest": None
        if arrival_steps is None
        else arrival_steps - table["fastest_success_steps"],
    }
    return table


def shaping_check(grid: np.ndarray, gamma: float, horizon: int) -> dict:
    """The stationary optimum of the assignment's reward plus a potential-based term pulling
    both agents to the target (Ng et al. 1999): the term cannot change what is optimal."""
    space = joint_dp.build_joint_space(grid)
    starts = space.start_states()
    transitions = joint_dp.build_transitions(space, "per_step")
    potential = joint_dp.distance_potential(space)
    plain = joint_dp.solve_stationary(transitions, gamma)
    shaped = joint_dp.solve_stationary(
        joint_dp.with_potential_shaping(transitions, potential, gamma), gamma
    )
    episodes = joint_dp.roll_out(space, transitions, shaped, starts, horizon)
    measures = episode_measures(episodes.positions, episodes.lengths, episodes.successes, grid)
    return {
        "problem": "stationary",
        "reward": "per_step",
        "potential": "-(path distance of A to the target + path distance of B)",
        "max_value_change_beyond_potential": float(
            np.abs(shaped.values[0] - (plain.values[0] - potential)).max()
        ),
        "shaped_optimum": measures,
    }


def open_batch(models_dir: Path, reward: str, grid: np.ndarray, horizon: int) -> Experiment:
    """The trained batch in ``models_dir`` (its manifest's runs and settings, every model
    file checked, see ``analysis.runs.read_experiment``), trained on ``reward``, on ``grid``,
    with episodes of ``horizon`` steps (errors name the folder)."""
    experiment = read_experiment(reward, models_dir)
    if experiment is None:
        raise FileNotFoundError(f"no trained models (<mode>_seed<seed>_agent_A.pt) in {models_dir}")
    if (found := experiment.settings["reward_mode"]) != reward:
        raise ValueError(f"{models_dir} holds agents trained with reward {found!r}, not {reward!r}")
    if not np.array_equal(experiment.grid, grid):
        raise ValueError(f"{models_dir} holds agents trained on another map than --map_seed")
    if int(experiment.settings["max_steps"]) != horizon:
        raise ValueError(f"{models_dir}: agents trained with max_steps != {horizon}")
    return experiment


def evaluate_batch(
    experiment: Experiment, grid: np.ndarray, horizon: int, episodes: int, epsilon: float
) -> dict[str, dict[str, list]]:
    """Measures of every trained seed: {mode: {"seeds": [...], condition: [measures per
    seed]}}, on the test episodes (start cells from ``EVAL_SEED``)."""
    env = VectorMultiAgentEnv(1, grid=grid, max_steps=horizon)
    batch: dict[str, dict[str, list]] = {}
    for mode in MODES:
        seeds = experiment.seeds.get(mode, [])
        entry: dict[str, list] = {"seeds": list(seeds), "greedy": [], "epsilon": []}
        for seed in seeds:
            models = load_model_pair(experiment.models_dir, mode, seed)
            evaluator = MultiAgentEvaluator(env, *models, epsilon=epsilon, seed=EVAL_SEED)
            runs = evaluator.run_conditions(episodes)  # greedy and ε-greedy, one batch
            for condition, results in zip(CONDITIONS, runs.values(), strict=True):
                positions = results.trajectories["positions"]
                measures = episode_measures(positions, results.lengths, results.successes, grid)
                entry[condition].append(measures)
        if seeds:
            batch[mode] = entry
    return batch


def seed_summary(batch: dict[str, dict[str, list]]) -> dict:
    """Mean, 95 % bootstrap CI over seeds, IQM and per-seed values of every measure."""
    summary: dict = {}
    for mode, entry in batch.items():
        summary[mode] = {"seeds": entry["seeds"]}
        for condition in CONDITIONS:
            summary[mode][condition] = {
                name: seed_statistics([seed[name] for seed in entry[condition]])
                for name in MEASURES
            }
    return summary


def verdicts(learned: dict) -> dict:
    """Per mode and condition: does training on the literal reward earn more of it while
    succeeding less than training on the arrival reward? Computed from the seed means."""
    result: dict = {}
    for mode in MODES:
        if mode not in learned.get("per_step", {}) or mode not in learned.get("arrival", {}):
            continue
        result[mode] = {}
        for condition in CONDITIONS:
            literal = learned["per_step"][mode][condition]
            arrival = learned["arrival"][mode][condition]

            def gap(name: str, low: dict = literal, high: dict = arrival) -> dict:
                separated = low[name]["ci95"][0] > high[name]["ci95"][1] or (
                    low[name]["ci95"][1] < high[name]["ci95"][0]
                )
                return {
                    "per_step_trained": low[name]["mean"],
                    "arrival_trained": high[name]["mean"],
                    "difference": low[name]["mean"] - high[name]["mean"],
                    "ci95_separated": bool(separated),
                }

            returns, success = gap("return_assignment"), gap("success_rate")
            more_return = returns["difference"] > 0
            less_success = success["difference"] < 0
            result[mode][condition] = {
                "return_assignment": returns,
                "success_rate": success,
                "literal_earns_more_assignment_return": bool(more_return),
                "literal_succeeds_less": bool(less_success),
                "literal_reward_misspecified": bool(more_return and less_success),
            }
    cases = [case for by_condition in result.values() for case in by_condition.values()]
    result["all_cases_misspecified"] = bool(cases) and all(
        case["literal_reward_misspecified"] for case in cases
    )
    result["cases_misspecified"] = sum(case["literal_reward_misspecified"] for case in cases)
    result["cases"] = len(cases)
    return result


def build_parser() -> argparse.ArgumentParser:
    """The study's command-line flags."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add = parser.add_argument
    add(
        "--per_step_models",
        type=Path,
        default=STUDY_DIR / "per_step" / "agent_models",
        help=(
            "agent_models folder of the batch trained on the assignment's reward "
            "(default: results/studies/reward/per_step/agent_models)"
        ),
    )
    add(
        "--arrival_models",
        type=Path,
        default=STUDY_DIR / "arrival" / "agent_models",
        help=(
            "agent_models folder of the batch trained on the arrival reward "
            "(default: results/studies/reward/arrival/agent_models)"
        ),
    )
    add(
        "--output_dir",
        type=Path,
        default=STUDY_DIR,
        help="where reward_study.json and .png go (default: results/studies/reward)",
    )
    add("--num_episodes", type=int, default=1000, help="test episodes per seed (default 1000)")
    add(
        "--epsilon",
        type=float,
        default=EVAL_EPSILON,
        help="exploration rate of the epsilon-greedy condition (default %(default)s)",
    )
    add(
        "--map_seed",
        type=int,
        default=DEFAULT_MAP_SEED,
        help="map of the DP; the batches must be trained on it (default %(default)s)",
    )
    add(
        "--gamma",
        type=float,
        default=joint_dp.GAMMA,
        help="discount of the DP, in (0, 1) (default %(default)s)",
    )
    add(
        "--max_steps",
        type=int,
        default=joint_dp.HORIZON,
        help="episode length of the DP and the evaluation (default %(default)s)",
    )
    add("--dp_only", action="store_true", help="compute the exact DP only (no trained agents)")
    add(
        "--plot_only",
        action="store_true",
        help="only redraw reward_study.png from the reward_study.json in --output_dir",
    )
    return parser


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.plot_only:
        if not (args.output_dir / "reward_study.json").is_file():
            parser.error(f"--plot_only: {args.output_dir / 'reward_study.json'} does not exist")
        return args
    if args.num_episodes < 1:
        parser.error(f"--num_episodes must be a positive integer, got {args.num_episodes}")
    if not 0 <= args.epsilon <= 1:
        parser.error(f"--epsilon must lie in [0, 1], got {args.epsilon}")
    if not 0 < args.gamma < 1:
        parser.error(f"--gamma must lie in (0, 1), got {args.gamma}")
    if args.max_steps < 1:
        parser.error(f"--max_steps must be a positive integer, got {args.max_steps}")
    if not args.dp_only:
        for flag in ("per_step_models", "arrival_models"):
            if not getattr(args, flag).is_dir():
                parser.error(f"--{flag}: folder {getattr(args, flag)} does not exist")
    return args


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    args = parse_args(argv)
    if args.plot_only:
        study = json.loads((args.output_dir / "reward_study.json").read_text(encoding="utf-8"))
        plot_study(study, args.output_dir / "reward_study.png")
        print(f"wrote {args.output_dir / 'reward_study.png'}")
        return study
    torch.set_num_threads(1)
    grid = generate_map((10, 10), args.map_seed)
    folders = (
        {} if args.dp_only else {"per_step": args.per_step_models, "arrival": args.arrival_models}
    )
    batches = {
        reward: open_batch(folder, reward, grid, args.max_steps)
        for reward, folder in folders.items()
    }  # checked before any work
    study: dict = {
        "protocol": {
            "map_seed": args.map_seed,
            "grid": grid.tolist(),
            "target": [int(i) for i in np.argwhere(grid == TARGET)[0]],
            "max_steps": args.max_steps,
            "test_episodes": args.num_episodes,
            "evaluation_seed": EVAL_SEED,
            "conditions": {"greedy": 0.0, "epsilon": args.epsilon},
            "statistics": "mean over training seeds, 95 % percentile bootstrap CI over seeds",
            "measures": MEASURES,
        },
        "exact_dp": exact_dp(grid, args.gamma, args.max_steps),
        "shaping_check": shaping_check(grid, args.gamma, args.max_steps),
    }
    if batches:
        study["learned"] = {
            reward: seed_summary(
                evaluate_batch(batch, grid, args.max_steps, args.num_episodes, args.epsilon)
            )
            for reward, batch in batches.items()
        }
        study["verdict"] = verdicts(study["learned"])
    print(format_table(study))
    write_json_atomic(args.output_dir / "reward_study.json", study)
    plot_study(study, args.output_dir / "reward_study.png")
    print(f"wrote {args.output_dir}")
    return study


if __name__ == "__main__":
    run_command(main)
