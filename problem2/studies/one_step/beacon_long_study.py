"""The listener at two million steps on maps never seen (the held-out test): the R + H + D cell
that passed its confirmation on training seeds (``beacon_long.py``), tested on the held-out maps.

    python -m studies.one_step.beacon_long_study     # 35 runs of 2 M steps, then the tests
    python -m studies.one_step.beacon_long_study --plot_only   # redraw the figure
    python -m studies.one_step.beacon_long_study --summary_only   # the JSON from its runs

Exactly as ``beacon_study`` tests the screen's winner (its ``train_and_test`` and
``drawn_episode``; the GRU study's summary: success at ε = 0.05 and greedy on the 40 held-out
maps × 500 episodes, the channels replaced by another episode's at the same step or held
constant, CIC, homing moves while the partner waits), with the cell's options
(``beacon_screen.cell_changes("RHD")``, 2 M steps) for every mode: full and independent on
seeds 0–9 (the spread is the point), comm and distance on seeds 0–4. Full is compared, paired
by seed, with the independent agents trained the same way and with the best independent
agents of any training at any length: the screen's best independent cell (named by
``beacon_around.json``; its agents on seeds 0–4 were tested by ``beacon_study``, whose
``beacon.json`` holds their held-out success), the recipe's independent agents at 1 M steps
(``one_step_unseen/unseen.json``) and the recipe's independent agents trained here for 2 M
steps on seeds 0–4 (the one-step map-pool recipe, no listener option). The verdicts of the
rules fixed before the test (``VERDICTS``) are computed, not chosen: nothing here was tuned on
seeds 0–9.

Outputs: ``results/studies/beacon_long/held_out/`` (``beacon_long_study.json``,
``beacon_long_study.png``, ``agent_models/``, ``training_logs/``, ``timing.json``: wall
times, not a result), beside ``beacon_long.json`` (``make`` runs ``beacon_long`` first: it
rewrites the folder whole).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from safety import use_reproducible_matmul, write_json_atomic

import numpy as np
from analysis.stats import seed_statistics
from batch.plumbing import ProgressLine, run_jobs
from settings import available_cores

from studies import map_pool_study
from studies.memory import study as gru_study
from studies.memory.held_out_tests import CONDITIONS, beacon_homing
from studies.one_step import unseen
from studies.one_step.beacon_around import AROUND_DIR
from studies.one_step.beacon_long import LONG_DIR, LONGER
from studies.one_step.beacon_screen import (
    best_independent,
    cell_changes,
    check_workers,
    checked_held_out_args,
    config,
)
from studies.one_step.beacon_study import STUDY_DIR as SCREEN_STUDY_DIR
from studies.one_step.beacon_study import drawn_episode, train_and_test
from studies.staging import run_command, staged_output, study_main, write_timing

STUDY_DIR = LONG_DIR / "held_out"
CHANGES = cell_changes("RHD") | {"total_steps": LONGER}  # every mode: D acts only on distance
PAIRED_SEEDS = tuple(range(10))  # full and independent
OTHER_SEEDS = (0, 1, 2, 3, 4)  # comm, distance and the recipe's independent agents at 2 M
RECIPE_2M = "recipe_independent_2M"  # label of the recipe's independent runs at 2 M steps
RECIPE_CHANGES = {"total_steps": LONGER}  # the one-step map-pool recipe, no listener option
FULL_FLOOR, MARGIN = 0.50, 0.10  # the rules fixed before the test, success rates
VERDICTS = {
    "full_at_least_0.50": "full's mean held-out success at eps = 0.05 over seeds 0-9 >= 0.50",
    "full_minus_independent": "full - independent (trained the same way, paired by seed 0-9, "
    "eps = 0.05) has mean >= +10 points and its 95 % interval's lower end above 0",
    "full_above_best_independent": "full - each independent of any training (paired by seed "
    "0-4, eps = 0.05) has its 95 % interval's lower end above 0",
    "message_replaced_costs": "replacing the message by another episode's at the same step "
    "costs the full pair success (eps = 0.05) with the interval's upper end below 0",
    "distance_replaced_costs": "replacing the distance by another episode's at the same step "
    "costs the full pair success (eps = 0.05) with the interval's upper end below 0",
    "every_seed_at_least_0.68": "full >= 0.68 (the beacon explorer) on every seed",
}


def jobs_of(staging: Path, smoke: dict, episodes: int) -> list[tuple]:
    """The runs in order: full and independent seed by seed first, then comm, distance and the
    recipe's independent agents at 2 M steps."""
    jobs = [
        (m, m, s, CHANGES, staging, smoke, episodes)
        for s in PAIRED_SEEDS
        for m in ("full", "independent")
    ]
    jobs += [
        (m, m, s, CHANGES, staging, smoke, episodes)
        for m in ("comm", "distance")
        for s in OTHER_SEEDS
    ]
    jobs += [
        (RECIPE_2M, "independent", s, RECIPE_CHANGES, staging, smoke, episodes) for s in OTHER_SEEDS
    ]
    return jobs


def screen_best_independent(screen: dict, tested: dict) -> tuple[str, dict[int, dict]]:
    """The screen's best independent cell (``screen``: beacon_around.json) and its held-out
    success per seed as ``beacon_study`` measured it (``tested``: beacon.json)."""
    cell = best_independent(screen["cells"])
    recorded = tested["best_independent"]
    if recorded["cell"] != cell:
        raise SystemExit(f"beacon.json tested {recorded['cell']}, the screen's best is {cell}")
    per_seed = {c: recorded["success"][c]["per_seed"] for c in CONDITIONS}
    seeds = unseen.SEEDS[: len(per_seed["eps"])]
    return cell, {s: {c: per_seed[c][k] for c in CONDITIONS} for k, s in enumerate(seeds)}


def against(full: dict[int, dict], others: dict[int, dict]) -> dict[str, Any]:
    """``others``' success and full − others, per condition, paired on the seeds both have."""
    seeds = sorted(set(full) & set(others))
    return {
        "seeds": seeds,
        "success": {c: seed_statistics([others[s][c] for s in seeds]) for c in CONDITIONS},
        "full_minus": {
            c: seed_statistics([full[s][c] - others[s][c] for s in seeds]) for c in CONDITIONS
        },
    }


def verdicts(results: dict) -> dict[str, dict[str, Any]]:
    """The rules fixed before the test, each with its rule, the numbers it reads and whether it
    holds."""
    full = results["held_out"]["modes"]["full"]
    difference = results["held_out"]["differences"]["full-independent"]["eps"]
    best = {k: v["full_minus"]["eps"] for k, v in results["best_independent"].items()}
    replaced = full["interventions_delta_success"]
    rows = {
        "full_at_least_0.50": (full["eps"]["mean"], round(full["eps"]["mean"], 9) >= FULL_FLOOR),
        "full_minus_independent": (
            difference,
            round(difference["mean"], 9) >= MARGIN and difference["ci95"][0] > 0,
        ),
        "full_above_best_independent": (best, all(b["ci95"][0] > 0 for b in best.values())),
        "message_replaced_costs": (
            replaced["message.same_step"]["eps"],
            replaced["message.same_step"]["eps"]["ci95"][1] < 0,
        ),
        "distance_replaced_costs": (
            replaced["distance.same_step"]["eps"],
            replaced["distance.same_step"]["eps"]["ci95"][1] < 0,
        ),
        "every_seed_at_least_0.68": (
            full["eps"]["per_seed"],
            all(v >= 0.68 for v in full["eps"]["per_seed"]),
        ),
    }
    return {
        name: {"rule": VERDICTS[name], "value": value, "holds": bool(holds)}
        for name, (value, holds) in rows.items()
    }


def in_words(episode: dict) -> str:
    """The drawn episode told in a few sentences: who reached the target first, how the
    waiting agent's partner moved relative to it, and what the waiting agent said."""
    if not episode:
        return "no held-out episode of seed 0's full pair had one agent waiting 5 steps"
    positions, target = np.array(episode["positions"]), np.array(episode["target"])
    first, met = episode["first_on_target_step"], episode["met_at_step"]
    on = (positions[first] == target).all(axis=-1)
    waiter, mover = (0, 1) if on[0] else (1, 0)
    distance = np.array(episode["distance_cells"])
    steps = np.diff(distance[first:])
    messages = np.array(episode["messages"])[first:, waiter]
    return (
        f"Held-out map {episode['map_seed']}, episode {episode['episode']}: agent "
        f"{'AB'[waiter]} stands on the target at step {first}, {distance[first]:.1f} cells "
        f"from agent {'AB'[mover]}, which arrives at step {met}; over those {met - first} "
        f"steps the distance shrinks {int((steps < 0).sum())} times, grows "
        f"{int((steps > 0).sum())} times and stays {int((steps == 0).sum())} times; the "
        f"waiting agent's message is {messages.mean():.2f} on average "
        f"(min {messages.min():.2f}, max {messages.max():.2f})."
    )


def summarise(runs: list[dict], screen: dict, tested: dict, smoke: dict, episodes: int) -> dict:
    """The GRU study's summary of the cell's four modes, the comparisons and the verdicts."""
    mine = [r for r in runs if r["mode"] in unseen.MODES]
    cfg = config("full", 0, CHANGES, smoke)
    results = gru_study.summarise(
        cfg, mine, beacon_homing(episodes, cfg.max_steps), gru_study.read_no_memory()
    )
    results["description"] = (
        "one-step memory agents on the map pool trained 2 million steps with the listener's "
        "reverse starts (0.5), homing shaping (kappa 2) and distance change, tested on "
        "held-out maps"
    )
    results["cell"] = {"changes": CHANGES, "confirmed_by": "beacon_long.json (training seeds)"}
    full = {r["seed"]: r["success"] for r in mine if r["mode"] == "full"}
    recipe = unseen.read_json(unseen.STUDY_DIR / "unseen.json")
    recipe_1m = {s: recipe["runs"][f"independent_seed{s}"]["success"] for s in unseen.SEEDS}
    recipe_2m = {r["seed"]: r["success"] for r in runs if r["mode"] == RECIPE_2M}
    cell, screen_best = screen_best_independent(screen, tested)
    results["best_independent"] = {
        f"screen {cell}": against(full, screen_best)
        | {"changes": screen["cells"][cell]["changes"]},
        "recipe 1M": against(full, recipe_1m) | {"changes": {}},
        "recipe 2M": against(full, recipe_2m) | {"changes": RECIPE_CHANGES},
    }
    results["recipe_2M_runs"] = {
        f"{r['mode']}_seed{r['seed']}": {k: v for k, v in r.items() if k != "seconds"}
        for r in runs
        if r["mode"] == RECIPE_2M
    }
    results["departures_from_the_assignment"] = map_pool_study.DEPARTURES | {
        "memory": "the previous observation (masked like the current one) and a one-hot of "
        "the previous move as inputs (27)",
        "training options": "reverse starts, homing shaping and the distance's change for "
        "learning only (studies/one_step/beacon.py)",
    }
    results["one_step_recipe_held_out"] = recipe["held_out"]["modes"]
    results["screen_winner_held_out"] = tested["held_out"]["modes"]
    results["verdicts"] = verdicts(results)
    return results


def plot(path: Path, results: dict) -> None:
    """Held-out success at ε = 0.05 per mode: the recipe (1 M), the screen's winner (1 M) and
    this cell (2 M); explorers as lines (the recipe's independent agents at 2 M are in the
    JSON and the printed table: a fourth bar does not fit the report's width)."""
    arms = [
        (
            "recipe",
            "#dd8452",
            {m: s["eps"] for m, s in results["one_step_recipe_held_out"].items()},
        ),
        (
            "screen's winner",
            "#c4ad66",
            {m: s["eps"] for m, s in results["screen_winner_held_out"].items()},
        ),
        ("R+H+D 2M", "#55a868", {m: s["eps"] for m, s in results["held_out"]["modes"].items()}),
    ]
    unseen.plot_held_out_bars(path, arms)


def run_study(args: argparse.Namespace) -> dict:
    """Train and test the 35 runs; install the outputs whole."""
    confirmation = unseen.read_json(args.confirmation)
    if confirmation is None or not confirmation["pass_rule"]["passed"]:
        raise SystemExit(
            f"the cell's confirmation at {args.confirmation.resolve()} is missing or did not "
            "pass: the held-out study runs only if it passed (studies.one_step.beacon_long)"
        )
    screen, tested = unseen.read_json(args.screen), unseen.read_json(args.tested)
    if screen is None or tested is None:
        raise SystemExit(
            f"no screen at {args.screen.resolve()} or no beacon study at "
            f"{args.tested.resolve()}: run make p2-beacon first"
        )
    if args.summary_only:
        return write_summary(args.output_dir, recorded_runs(args.output_dir), screen, tested, args)
    with staged_output(args.output_dir) as staging:
        jobs = jobs_of(staging, args.smoke, args.episodes)
        steps = args.smoke.get("total_steps", LONGER)
        runs = run_jobs(train_and_test, jobs, args.workers, ProgressLine(len(jobs), steps))
        results = write_summary(staging, runs, screen, tested, args)
        write_timing(staging / "timing.json", runs)
    return results


def write_summary(
    folder: Path, runs: list[dict], screen: dict, tested: dict, args: argparse.Namespace
) -> dict:
    """Summarise ``runs`` (:func:`summarise`), draw seed 0's episode from the saved models and
    write the JSON and the figure into ``folder``."""
    results = summarise(runs, screen, tested, args.smoke, args.episodes)
    max_steps = config("full", 0, CHANGES, args.smoke).max_steps
    episode = drawn_episode(folder / "agent_models", max_steps, args.episodes)
    results["drawn_episode"] = episode | {"in_words": in_words(episode)}
    write_json_atomic(folder / "beacon_long_study.json", results)
    plot(folder / "beacon_long_study.png", results)
    return results


def recorded_runs(folder: Path) -> list[dict]:
    """Every run's results as the study's JSON in ``folder`` records them (no training)."""
    recorded = unseen.read_json(folder / "beacon_long_study.json")
    if recorded is None:
        raise SystemExit(f"no study at {folder.resolve()}: run it first (without --summary_only)")
    return [*recorded["runs"].values(), *recorded["recipe_2M_runs"].values()]


def format_study(results: dict) -> str:
    """Per seed full, independent and difference (points); the GRU study's table; the
    comparisons, the replaced channels and the verdicts."""
    modes = results["held_out"]["modes"]
    full, indep = modes["full"]["eps"], modes["independent"]["eps"]
    difference = results["held_out"]["differences"]["full-independent"]["eps"]
    lines = ["seed     full  indep   diff"]
    for k, seed in enumerate(modes["full"]["seeds"]):
        lines.append(
            f"{seed:<6} {full['per_seed'][k]:6.3f} {indep['per_seed'][k]:6.3f} "
            f"{100 * difference['per_seed'][k]:+6.1f}"
        )
    lines.append(gru_study.format_table(results))
    for name, entry in results["best_independent"].items():
        s, d = entry["success"]["eps"], entry["full_minus"]["eps"]
        lines.append(
            f"full - {name:<14} ({s['mean']:.3f}): eps {d['mean']:+.3f} "
            f"[{d['ci95'][0]:+.3f}, {d['ci95'][1]:+.3f}]"
        )
    for name, s in modes["full"]["interventions_delta_success"].items():
        e = s["eps"]
        lines.append(
            f"full, {name:<24} eps {e['mean']:+.3f} [{e['ci95'][0]:+.3f}, {e['ci95'][1]:+.3f}]"
        )
    lines.append(results["drawn_episode"]["in_words"])
    for name, verdict in results["verdicts"].items():
        lines.append(f"{name}: {'holds' if verdict['holds'] else 'does not hold'}")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    add = parser.add_argument
    add("--workers", type=int, default=available_cores(), help="processes (1..64)")
    add("--output_dir", type=Path, default=STUDY_DIR, help="folder written")
    add("--screen", type=Path, default=AROUND_DIR / "beacon_around.json", help="the screen's JSON")
    add("--tested", type=Path, default=SCREEN_STUDY_DIR / "beacon.json", help="beacon_study's JSON")
    add(
        "--confirmation",
        type=Path,
        default=LONG_DIR / "beacon_long.json",
        help="beacon_long's JSON: its pass rule must hold",
    )
    add("--plot_only", action="store_true", help="redraw the figure from the JSON (no runs)")
    add(
        "--summary_only",
        action="store_true",
        help="rebuild the JSON and figure from the runs it records and the saved models (no runs)",
    )
    add("--total_steps", type=int, default=None, help="smoke runs only: env steps per run")
    add("--episodes_per_map", type=int, default=None, help="smoke runs only: test episodes per map")
    args = parser.parse_args(argv)
    check_workers(parser, args)
    return checked_held_out_args(parser, args, STUDY_DIR)


def main(argv: list[str] | None = None) -> dict:
    use_reproducible_matmul()  # before the first matrix product
    return study_main(argv, parse_args, run_study, format_study, plot=("beacon_long_study", plot))


if __name__ == "__main__":
    run_command(main)
