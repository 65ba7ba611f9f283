"""How value iteration scales with the number of states.

    python bench/p1_scaling.py [--sizes 10 30 100 300]

Builds open square layouts (start top-left, goal bottom-right, a few obstacles and
penalty cells at seeded random places) and prints states, sweeps to convergence,
seconds, and seconds per sweep. Because each state has three outcomes per action,
a sweep is O(S) in time and memory: seconds per state should stay roughly flat.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "problem1"))
from environment import GridWorldEnv  # noqa: E402
from value_iteration import ValueIteration  # noqa: E402

SIZES = (10, 30, 100, 300)


def open_layout(size: int, seed: int = 0) -> list[str]:
    """``size`` x ``size`` layout with ``size`` obstacles and ``size // 2`` penalty cells.
    The top row and the right column stay free, so the goal is always reachable."""
    rng = np.random.default_rng(seed)
    cells = np.full((size, size), ".")
    cells[0, 0], cells[-1, -1] = "S", "G"
    interior = np.flatnonzero(cells[1:, :-1].ravel() == ".")
    interior = (interior // (size - 1) + 1) * size + interior % (size - 1)  # index in the grid
    chosen = rng.choice(interior, size + size // 2, replace=False)
    cells.ravel()[chosen[:size]] = "#"
    cells.ravel()[chosen[size:]] = "P"
    return ["".join(row) for row in cells]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description=__doc__,
        formatter_class=type(
            "Formatter",
            (argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter),
            {},
        ),
    )
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=list(SIZES), help="grid side lengths (>= 3)"
    )
    args = parser.parse_args(argv)
    if min(args.sizes) < 3:
        parser.error(f"argument --sizes: every size must be >= 3, got {min(args.sizes)}")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    print(
        f"{'grid':>9} {'states':>8} {'sweeps':>7} {'build s':>8} {'solve s':>8} "
        f"{'ms/sweep':>9} {'ns/state/sweep':>15}"
    )
    for size in args.sizes:
        start = time.perf_counter()
        solver = ValueIteration(GridWorldEnv(layout=open_layout(size)), gamma=0.95, epsilon=1e-4)
        built = time.perf_counter()
        _, sweeps = solver.solve(max_iterations=10_000)
        solved = time.perf_counter()
        per_sweep = (solved - built) / sweeps
        per_state_ns = per_sweep / solver.n_states * 1e9
        print(
            f"{size:>4}x{size:<4} {solver.n_states:8d} {sweeps:7d} {built - start:8.3f} "
            f"{solved - built:8.3f} {per_sweep * 1e3:9.3f} {per_state_ns:15.1f}"
        )


if __name__ == "__main__":
    main()
