"""Report tests: ``report/`` on ``sys.path`` and a generated fixture of results.

:func:`write_fixture` writes a small but complete tree shaped like the repository's
results (``problem1/results``, ``problem2/results`` with studies and evaluation), with
tiny PNGs, so the whole report can be built in seconds from known numbers.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

REPORT = Path(__file__).resolve().parents[2] / "report"
if str(REPORT) not in sys.path:
    sys.path.insert(0, str(REPORT))

MODES = ("independent", "comm", "full")
SEEDS = (1, 2, 3)
EPS_SUCCESS = {
    "independent": (0.30, 0.35, 0.40),
    "comm": (0.50, 0.55, 0.60),
    "full": (0.85, 0.88, 0.9),
}
P1_FIGURES = ("value_heatmap", "policy_arrows", "q_functions", "convergence", "comparison",
              "stochasticity_policies", "stochasticity_start_value")  # fmt: skip


def _json(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))


def _png(path: Path, shape: tuple[int, int] = (20, 30)) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(path, np.linspace(0, 1, shape[0] * shape[1]).reshape(shape))


def stats(values) -> dict:
    """A seed-statistics dict as analysis_stats.seed_statistics writes it (CI = range)."""
    values = [float(v) for v in values]
    return {"mean": float(np.mean(values)), "ci95": [min(values), max(values)],
            "iqm": float(np.mean(values)), "n": len(values), "per_seed": values}  # fmt: skip


def _final(mode: str, seed: int, success: float) -> dict:
    def condition(rate: float, epsilon: float) -> dict:
        return {"epsilon": epsilon, "episodes": 1000, "success_rate": rate,
                "mean_steps_to_success": 12.0, "mean_return": 1.0,
                "share_steps_one_on_target": 0.2,
                "share_episodes_one_never_arrives": 0.1}  # fmt: skip

    return {"mode": mode, "seed": seed, "greedy": condition(success - 0.1, 0.0),
            "eps": condition(success, 0.05)}  # fmt: skip


def _training_root(root: Path, modes=MODES, success=EPS_SUCCESS, per_step: bool = False) -> None:
    logs = root / "training_logs"
    logs.mkdir(parents=True, exist_ok=True)
    for mode in modes:
        for k, seed in enumerate(SEEDS):
            final = _final(mode, seed, success[mode][k])
            if per_step:
                final["eps"] |= {"success_rate": 0.04, "share_steps_one_on_target": 0.8,
                                 "share_episodes_one_never_arrives": 0.9}  # fmt: skip
            _json(logs / f"{mode}_seed{seed}_final.json", final)
            with (logs / f"{mode}_seed{seed}.csv").open("w", newline="") as handle:
                writer = csv.writer(handle)
                writer.writerow(["env_steps", "episodes", "updates", "epsilon", "loss", "mean_q",
                                 "train_return", "train_success", "eval_success_greedy",
                                 "eval_success_eps", "eval_return_greedy",
                                 "eval_return_eps"])  # fmt: skip
                writer.writerow([0, 0, 0, 1.0, "nan", "nan", "nan", "nan", 0.0, 0.0, -9, -9])
                writer.writerow([1000, 20, 10, 0.5, 0.1, 0.2, -1, 0.1, 0.2, 0.3, -2, -1])


def _performance_modes(success) -> dict:
    modes = {}
    for mode, values in success.items():
        failures = {"swapping": stats([0.5]), "parked": stats([0.2]), "looping": stats([0.2]),
                    "other": stats([0.1])}  # fmt: skip
        entry = {"label": mode, "seeds": list(SEEDS), "best_seed": SEEDS[-1], "per_seed": {}}
        for condition, shift in (("greedy", -0.1), ("eps", 0.0)):
            entry[condition] = {
                "epsilon": 0.05 if condition == "eps" else 0.0,
                "episodes_per_seed": 1000,
                "success_rate": stats([v + shift for v in values]),
                "mean_steps_to_success": stats([12.0, 13.0, 14.0]),
                "mean_return": stats([1.0, 2.0, 3.0]),
                "failures": failures,
            }
        modes[mode] = entry
    return modes


def _baselines(target) -> dict:
    return {"random": {"episodes": 1000, "success_rate": 0.002, "mean_steps_to_success": 8.5,
                       "mean_return": -9.3},
            "oracle": {"episodes": 1000, "success_rate": 1.0, "mean_steps_to_success": 9.6,
                       "mean_return": 10.2}}  # fmt: skip


def write_fixture(root: Path) -> Path:
    """Write the complete fixture under ``root``; return ``root``."""
    p1 = root / "problem1" / "results"
    values = np.linspace(4.0, 9.5, 25)
    values[[7, 11, 24]] = 0.0
    policy = np.array([1, 1, 1, 1, 2, 0, 0, 0, 1, 2, 0, 0, 1, 1, 2, 1, 1, 2, 1, 2, 1, 1, 1, 1, 0])
    q = np.repeat(values[:, None], 4, axis=1) - np.arange(4)[None, :] * 0.3
    p1.mkdir(parents=True)
    np.savez(p1 / "value_function.npz", values=values, iterations=31, history=np.ones(31))
    np.savez(p1 / "q_function.npz", q_values=q, iterations=31, history=np.ones(31))
    np.savez(p1 / "optimal_policy.npz", policy=policy, vi_policy=policy, qi_policy=policy)
    solver = {"iterations": 31, "converged": True, "wall_time_s": 0.002,
              "seconds_per_sweep": 5e-5, "final_change": 5e-5, "bellman_residual": 3e-5,
              "v_start": 4.9}  # fmt: skip
    _json(p1 / "summary.json", {
        "gamma": 0.95, "epsilon": 1e-4, "seed": 641, "start_state": 0, "v_start": 4.9,
        "value_iteration": solver, "q_iteration": solver | {"seconds_per_sweep": 4.8e-5},
        "max_value_difference_vi_qi": 0.0, "policies_agree": True, "policies_identical": True,
        "verification": {"policy_evaluation_max_error": 7e-5, "residual_bound": 6e-4,
                         "within_bound": True,
                         "monte_carlo": {"episodes": 10000, "mean_return": 4.9,
                                         "ci99": [4.86, 4.95], "contains_v_start": True}},
    })  # fmt: skip
    settings = []
    for k, drift in enumerate((0.0, 0.1, 0.3)):
        settings.append({"drift": drift, "prob_intended": 1 - 2 * drift, "iterations": 11 + 30 * k,
                         "v_start": 6.4 - 2.5 * k, "expected_steps": 8.0 + 10 * k,
                         "expected_penalty_visits": [0.0, 0.14, 0.0][k],
                         "values": (values - k).clip(0).tolist(), "policy": policy.tolist(),
                         "detour_states": [[], [], [0, 6]][k]})  # fmt: skip
    _json(p1 / "stochasticity_study.json", {"gamma": 0.95, "epsilon": 1e-4,
                                            "reference_drift": 0.1,
                                            "settings": settings})  # fmt: skip
    for name in P1_FIGURES:
        _png(p1 / "visualizations" / f"{name}.png")

    p2 = root / "problem2" / "results"
    grid = np.zeros((10, 10), dtype=int)
    grid[0, 7] = grid[4, 7] = 1
    grid[8, 1] = 2
    _json(p2 / "agent_models" / "map.json", {"grid": grid.tolist()})
    _json(p2 / "agent_models" / "hyperparameters.json", {
        "map_seed": 641, "grid_size": 10, "max_steps": 50, "reward_mode": "arrival",
        "total_steps": 200000, "num_envs": 64, "batch_size": 256, "lr": 5e-4,
        "lr_end_factor": 0.1, "gamma": 0.99, "epsilon_start": 1.0, "epsilon_end": 0.05,
        "epsilon_decay": 0.5, "hidden_dim": 64, "target_update": 250, "buffer_size": 100000,
        "learning_starts": 5000, "updates_per_step": 2, "max_grad_norm": 10.0,
        "comm_learning": "dial", "comm_noise": 1.0, "dueling": False, "prioritized": False,
        "eval_interval": 10000, "eval_episodes": 200, "num_seeds": 3, "seed": 1,
    })  # fmt: skip
    _training_root(p2)
    _json(p2 / "training_logs" / "timing.json", {f"full_seed{s}": 60.0 + s for s in SEEDS})
    _png(p2 / "training_logs" / "training_curves.png", (30, 40))
    _training_root(p2 / "studies" / "per_step", ("full",), per_step=True)
    low = {m: tuple(v - 0.1 for v in EPS_SUCCESS[m]) for m in MODES}
    _training_root(p2 / "studies" / "no_dial", ("comm", "full"), low)
    for k in range(2):
        _training_root(p2 / "studies" / "map_panel" / f"map{k}")

    evaluation = p2 / "evaluation_results"
    _json(evaluation / "baselines.json", {"maps": {str(s): _baselines(None) | {"target": [8, 1]}
                                                   for s in (641, 0, 1)}})  # fmt: skip
    experiments = {
        "main": {
            "map_seed": 641,
            "target": [8, 1],
            "grid": grid.tolist(),
            "baselines": _baselines(None),
            "modes": _performance_modes(EPS_SUCCESS),
        },
        "per_step": {
            "map_seed": 641,
            "target": [8, 1],
            "baselines": _baselines(None),
            "modes": _performance_modes({"full": (0.03, 0.04, 0.05)}),
        },
        "no_dial": {
            "map_seed": 641,
            "target": [8, 1],
            "baselines": _baselines(None),
            "modes": _performance_modes({m: low[m] for m in ("comm", "full")}),
        },
    }
    for k in range(2):
        experiments[f"map_panel/map{k}"] = {"map_seed": k, "target": [8, 1],
                                            "baselines": _baselines(None),
                                            "modes": _performance_modes(EPS_SUCCESS)}  # fmt: skip
    definitions = {"window": "the last 10 steps", "swapping": "trading places",
                   "parked": "one parked", "looping": "a loop", "other": "the rest"}  # fmt: skip
    _json(evaluation / "performance.json", {"protocol": {"failure_definitions": definitions},
                                            "experiments": experiments})  # fmt: skip
    correlations = {a: {"on_target": {"r": 0.7}, "sees_target": {"r": 0.3},
                        "target_distance": {"r": -0.5}, "agent_distance": {"r": None},
                        "time_step": {"r": 0.1}} for a in "AB"}  # fmt: skip
    comm_modes = {"independent": {"label": "independent", "per_seed": {}}}
    for mode, diff in (("comm", [0.05, 0.1, 0.15]), ("full", [-0.02, 0.0, 0.03])):
        causal = {c: {"real": stats([0.8]), "shuffled": stats([0.7]), "zeroed": stats([0.5]),
                      "real_minus_shuffled": stats(diff), "real_minus_zeroed": stats([0.3])}
                  for c in ("greedy", "eps")}  # fmt: skip
        comm_modes[mode] = {"label": mode, "causal": causal,
                            "per_seed": {str(s): {"correlations": correlations}
                                         for s in SEEDS}}  # fmt: skip
    _json(evaluation / "communication_analysis.json",
          {"experiments": {"main": {"map_seed": 641, "modes": comm_modes}}})  # fmt: skip
    maps = {str(s): {"target": [s, 2], "random": {"success_rate": 0.01},
                     "oracle": {"success_rate": 1.0, "mean_steps_to_success": 8.0},
                     "modes": {m: {"greedy": stats([0.1, 0.2]), "eps": stats([0.2, 0.3])}
                               for m in MODES}} for s in range(3)}  # fmt: skip
    _json(evaluation / "generalization.json", {
        "trained_map_seed": 641, "episodes_per_map": 500, "epsilon": 0.05, "map_seeds": [0, 1, 2],
        "maps": maps, "mean_over_maps": {m: {"greedy": stats([0.15, 0.15]),
                                             "eps": stats([0.25, 0.25])} for m in MODES},
    })  # fmt: skip
    _png(evaluation / "trajectories.png", (40, 30))
    _png(evaluation / "comm_heatmap.png", (20, 40))
    return root


@pytest.fixture(scope="module")
def fixture_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_fixture(tmp_path_factory.mktemp("results"))
