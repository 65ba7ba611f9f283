"""Reference policies for problem 2 (they run through ``rollout.run_episodes`` like the agents).

* :func:`random_policy`: uniform random actions and messages.
* :func:`oracle_policy` (defined in ``analysis/episodes.py``, beside the agents' policy):
  full information; each agent follows a shortest path to the target (breadth-first
  distances) and the first to arrive waits there.
* :func:`explorer_policy`: memoryless, from the agent's own patch only: on the target, stay;
  target in sight, step towards it; otherwise a random unblocked move. With
  ``sweep=True`` the agent keeps its direction until blocked (one heading of state).
* :func:`beacon_explorer_policy`: the sweeping explorer that says "I am on the target" with
  its message and, hearing it, homes in on the partner by the distance it observes.

``python baselines.py`` evaluates them on the default map (seed 641) and map seeds 0–4,
prints a one-line summary and writes ``results/evaluation_results/baselines.json``.
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

from safety import use_reproducible_matmul, write_json_atomic

import numpy as np
from rollout import EVAL_SEED, PolicyFn, evaluate_policy
from vector_env import (
    ACTION_DELTAS,
    DEFAULT_MAP_SEED,
    FREE,
    REWARD_MODES,
    TARGET,
    VectorMultiAgentEnv,
    generate_map,
)

from analysis.console import repository_path
from analysis.episodes import oracle_policy

RESULTS_DIR = Path(__file__).resolve().parent.parent / "results" / "evaluation_results"
MAP_SEEDS = (DEFAULT_MAP_SEED, 0, 1, 2, 3, 4)


def random_policy(seed: int | None = None) -> PolicyFn:
    """Uniform random actions in 0..4 and messages in [0, 1]."""
    rng = np.random.default_rng(seed)

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(obs)
        return rng.integers(len(ACTION_DELTAS), size=(n, 2)), rng.random((n, 2))

    return act


STAY = len(ACTION_DELTAS) - 1
PERPENDICULAR = np.array([[2, 3], [2, 3], [0, 1], [0, 1]])  # Up Down Left Right -> the two across
ON_TARGET_MESSAGE = 1.0  # the beacon explorer's "I am on the target"


def _patch_moves(obs: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From each agent's own patch (observation elements 0 .. w² − 1 of obs (N, 2, D)):
    which of Up, Down, Left, Right is unblocked (N, 2, 4), whether the target is in sight
    (N, 2), and the move towards it (N, 2): Stay on it, else vertically first when that cell
    is open."""
    centre = w * w // 2
    neighbours = np.array([centre - w, centre + w, centre - 1, centre + 1])  # Up Down Left Right
    offsets = np.stack(np.divmod(np.arange(w * w), w), axis=-1) - w // 2  # (w², 2)
    patch = obs[..., : w * w]  # (N, 2, w²)
    around = patch[..., neighbours]  # (N, 2, 4)
    open_moves = (around == FREE) | (around == TARGET)
    seen = patch == TARGET
    d_row, d_col = np.moveaxis(offsets[np.argmax(seen, axis=-1)], -1, 0)  # (N, 2) each
    vertical, horizontal = np.where(d_row < 0, 0, 1), np.where(d_col < 0, 2, 3)
    vertical_open = np.take_along_axis(open_moves, vertical[..., None], axis=-1)[..., 0]
    toward = np.where((d_row != 0) & (vertical_open | (d_col == 0)), vertical, horizontal)
    toward = np.where((d_row == 0) & (d_col == 0), STAY, toward)
    return open_moves, seen.any(axis=-1), toward


def _is_open(open_moves: np.ndarray, moves: np.ndarray) -> np.ndarray:
    return np.take_along_axis(open_moves, moves[..., None], axis=-1)[..., 0]


def explorer_policy(seed: int | None = None, sweep: bool = False, obs_window: int = 3) -> PolicyFn:
    """Memoryless explorer on each agent's own patch (observation elements 0 .. w² − 1):
    Stay on the target; with the target in sight, step towards it (vertically first when
    that cell is open); otherwise a uniformly random move among the unblocked ones. With
    ``sweep``, keep the current heading while it is unblocked (a new random one when
    blocked). Sends the message 0."""
    rng = np.random.default_rng(seed)
    heading: np.ndarray | None = None

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nonlocal heading
        open_moves, visible, toward = _patch_moves(obs, obs_window)
        random_move = np.argmax(rng.random(open_moves.shape) + open_moves, axis=-1)  # (N, 2)
        move = random_move
        if sweep:
            if heading is None or heading.shape != random_move.shape:
                heading = random_move
            heading = move = np.where(_is_open(open_moves, heading), heading, random_move)
        actions = np.where(visible, toward, move)
        return actions, np.zeros(actions.shape)

    return act


def beacon_explorer_policy(seed: int | None = None, obs_window: int = 3) -> PolicyFn:
    """The sweeping explorer with a beacon: it uses the message and the distance.

    * Message: ``ON_TARGET_MESSAGE`` (1) while the agent stands on the target, else 0.
    * While the partner's message (observation element w²) says it is on the target, the
      distance to the partner (element w² + 1) is the distance to the target, and the agent
      homes in on it: it keeps its heading while the distance did not grow on the last step
      and turns to a random unblocked perpendicular heading when it grew (or when blocked).
    * Otherwise, and with the target in sight, it acts as ``explorer_policy(sweep=True)``.
    State: the heading and the distance of the previous step, per agent (like the sweeping
    explorer, no map and no memory of where it has been)."""
    rng = np.random.default_rng(seed)
    w = obs_window
    heading: np.ndarray | None = None
    last_distance: np.ndarray | None = None

    def act(obs: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nonlocal heading, last_distance
        open_moves, visible, toward = _patch_moves(obs, w)
        partner_on_target = obs[..., w * w] >= 0.5
        distance = obs[..., w * w + 1]
        random_move = np.argmax(rng.random(open_moves.shape) + open_moves, axis=-1)  # (N, 2)
        if heading is None or heading.shape != random_move.shape:
            heading, last_distance = random_move, distance
        across = PERPENDICULAR[heading]  # (N, 2, 2)
        across_open = np.take_along_axis(open_moves, across, axis=-1)  # (N, 2, 2)
        pick = np.argmax(rng.random(across_open.shape) + across_open, axis=-1)
        turn = np.take_along_axis(across, pick[..., None], axis=-1)[..., 0]
        turn = np.where(across_open.any(axis=-1), turn, random_move)
        farther = partner_on_target & (distance > last_distance + 1e-6)
        heading = np.where(farther, turn, heading)
        heading = np.where(_is_open(open_moves, heading), heading, random_move)
        last_distance = distance
        actions = np.where(visible, toward, heading)
        on_target = obs[..., (w * w) // 2] == TARGET
        return actions, np.where(on_target, ON_TARGET_MESSAGE, 0.0)

    return act


POLICIES = {
    "random": lambda grid, seed: random_policy(seed),
    "oracle": lambda grid, seed: oracle_policy(grid),
    "explorer": lambda grid, seed: explorer_policy(seed),
    "sweep_explorer": lambda grid, seed: explorer_policy(seed, sweep=True),
    "beacon_explorer": lambda grid, seed: beacon_explorer_policy(seed),
}
POLICY_LABELS = {  # each policy's name in figures, as the report names it (report/data.typ)
    "random": "random actions",
    "oracle": "shortest-path oracle",
    "explorer": "explorer",
    "sweep_explorer": "sweeping explorer",
    "beacon_explorer": "beacon explorer",
}


def evaluate_baselines(
    num_episodes: int = 1000, map_seeds: tuple[int, ...] = MAP_SEEDS, seed: int = EVAL_SEED
) -> dict:
    """Random and oracle policies on each map, under both reward modes (the episodes and
    so success and steps are the same in both; only the return differs)."""
    maps = {}
    for map_seed in map_seeds:
        grid = generate_map((10, 10), map_seed)
        entry: dict = {"grid": grid.tolist()}
        for name, factory in POLICIES.items():
            make_policy = partial(factory, grid, seed)
            for mode in REWARD_MODES:
                env = VectorMultiAgentEnv(min(num_episodes, 1000), grid=grid, reward_mode=mode)
                summary = evaluate_policy(env, make_policy(), num_episodes, seed)
                entry.setdefault(name, {k: v for k, v in summary.items() if k != "mean_return"})
                entry[name][f"mean_return_{mode}"] = summary["mean_return"]
        entry["target"] = list(env.target_position)
        maps[str(map_seed)] = entry
    protocol = {
        "grid_size": [10, 10],
        "max_steps": 50,
        "episodes": num_episodes,
        "evaluation_seed": seed,
        "success": "both agents on the target within 50 steps",
    }
    return {"protocol": protocol, "maps": maps}


def summary(results: dict) -> str:
    """One line: each policy's success on the first map, and what was evaluated."""
    map_seed, entry = next(iter(results["maps"].items()))
    rates = ", ".join(f"{name} {entry[name]['success_rate']:.1%}" for name in POLICIES)
    return (
        f"baselines on {len(results['maps'])} maps ({results['protocol']['episodes']} episodes "
        f"each); success on map {map_seed}: {rates}"
    )


def int_list(text: str) -> list[int]:
    """``"0,1"`` -> [0, 1] (argparse type; with nargs="+" both ``0,1`` and ``0 1`` work)."""
    try:
        return [int(part) for part in text.split(",") if part.strip()]
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"expected integers, got {text!r}") from error


def main(argv: list[str] | None = None) -> None:
    use_reproducible_matmul()  # before the first matrix product
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description=__doc__.split("\n\n")[0],
        epilog="Relative paths are resolved against the current folder.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--episodes", type=int, default=1000, help="test episodes per map")
    parser.add_argument("--seed", type=int, default=EVAL_SEED, help="seed of the start cells")
    parser.add_argument(
        "--map_seeds",
        "--map-seeds",
        type=int_list,
        nargs="+",
        default=",".join(map(str, MAP_SEEDS)),
        help="map seeds, as 641,0,1 or 641 0 1",
    )
    parser.add_argument(
        "--output", type=Path, default=RESULTS_DIR / "baselines.json", help="JSON file written"
    )
    args = parser.parse_args(argv)
    parts = args.map_seeds  # a list of lists from the command line, one list by default
    map_seeds = tuple(s for part in parts for s in (part if isinstance(part, list) else [part]))
    if not 1 <= args.episodes <= 100_000:
        parser.error(f"--episodes must be an integer in 1..100000, got {args.episodes}")
    if not map_seeds or min(map_seeds) < 0 or len(set(map_seeds)) != len(map_seeds):
        parser.error(f"--map_seeds must be distinct non-negative integers, got {map_seeds}")
    if args.seed < 0:
        parser.error(f"--seed must be a non-negative integer, got {args.seed}")
    results = evaluate_baselines(args.episodes, map_seeds, seed=args.seed)
    write_json_atomic(args.output, results)
    print(summary(results))
    print(f"wrote {repository_path(args.output)}")


if __name__ == "__main__":
    main()
