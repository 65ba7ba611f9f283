"""A clock or any changing input? Memoryless agents whose distance input is replaced.

    python -m studies.one_step.clock --train     # train both variants, then measure
    python -m studies.one_step.clock             # measure from the trained batches

The report's hypothesis: on the maps where memoryless agents fail (``why.MAPS``), the
distance helps as a value that changes during the episode, not as news of the partner. This
control trains memoryless *distance* agents (the message zeroed) whose element 10, the
distance, is replaced in training and test by

- ``clock``: the step of the episode over ``max_steps`` (0 at the start), a pure clock;
- ``noise``: a uniform random number in [0, 1), one per copy and step, changing but timeless.

Seeds 641-645, the main recipe, as the map panel. Each pair is tested on the panel's protocol
(its 1000 test episodes per seed and exploration draws) and compared, paired by seed, with the
panel's independent and distance agents on the same episodes.
Outputs: ``memory_panel/clock/clock.json``.
"""

from __future__ import annotations

from typing import Any

from safety import make_console_safe, use_reproducible_matmul, write_json_atomic

import numpy as np
import torch
from analysis.stats import seed_statistics
from rollout import EVAL_SEED
from trainer import DQNTrainer
from vector_env import VectorMultiAgentEnv

from studies.one_step import why
from studies.one_step.panel import (
    CONDITIONS,
    MEMORY_PANEL_DIR,
    SEEDS,
    memoryless_rates,
    paired,
    read_batch,
    successes,
)
from studies.one_step.why import MAPS
from studies.panel import PANEL_DIR
from studies.staging import run_command

CLOCK_DIR = MEMORY_PANEL_DIR / "clock"
MODE = "distance"  # the message zeroed, element 10 kept: here the replaced input
NOISE_SEED = 0


class ClockEnv(VectorMultiAgentEnv):
    """Observations whose distance element holds the step of the episode over ``max_steps``:
    0 when an episode starts, k / max_steps after k steps (also in ``final_obs``)."""

    def replaced(self, steps: np.ndarray) -> np.ndarray:
        """The value (N,) that stands in for the distance, from each copy's step (N,)."""
        return steps / self.max_steps

    # The distance is an observation's last element, whatever the window (patch, message, distance).
    def current_observations(self) -> np.ndarray:
        obs = super().current_observations()
        obs[:, :, -1] = self.replaced(self._steps)[:, None]
        return obs

    def step(self, actions: np.ndarray, messages: np.ndarray) -> tuple:
        obs, rewards, terminated, truncated, info = super().step(actions, messages)
        info["final_obs"][:, :, -1] = self.replaced(info["steps"])[:, None]
        obs[:, :, -1] = self.replaced(self._steps)[:, None]  # a restarted copy's step is 0
        return obs, rewards, terminated, truncated, info


class NoiseEnv(ClockEnv):
    """Observations whose distance element holds a fresh uniform draw in [0, 1) per copy and
    step (both agents of a copy read the same draw, as they read the same distance)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._noise = np.random.default_rng(NOISE_SEED)  # before the base class's first reset
        super().__init__(*args, **kwargs)

    def replaced(self, steps: np.ndarray) -> np.ndarray:
        return self._noise.random(len(steps))


class ClockTrainer(DQNTrainer):
    vector_env_class = ClockEnv


class NoiseTrainer(DQNTrainer):
    vector_env_class = NoiseEnv


VARIANTS = {"clock": ClockTrainer, "noise": NoiseTrainer}  # each trains and tests in its env


def variant_rates(variant: str, map_seed: int, episodes: int) -> dict[str, list[float]]:
    """Per condition the success rate of each seed's pair (S,) in the variant's own env."""
    models_dir = CLOCK_DIR / variant / f"map{map_seed}" / "agent_models"
    grid, max_steps = read_batch(models_dir)
    env_class = VARIANTS[variant].vector_env_class
    rates: dict[str, list[float]] = {c: [] for c in CONDITIONS}
    for seed in SEEDS:
        found = successes(models_dir, MODE, seed, grid, max_steps, episodes, env_class)
        for condition, success in found.items():
            rates[condition].append(float(success.mean()))
    return rates


def measure_map(map_seed: int, episodes: int) -> dict[str, Any]:
    """Success of both variants and of the panel's independent and distance agents, and the
    paired differences that place each variant between them."""
    models_dir = CLOCK_DIR / "clock" / f"map{map_seed}" / "agent_models"
    grid, max_steps = read_batch(models_dir)
    panel, source = memoryless_rates(map_seed, PANEL_DIR, grid, max_steps, episodes)
    found = {v: variant_rates(v, map_seed, episodes) for v in VARIANTS}
    success, differences = {}, {}
    for name, rates in (("independent", panel["independent"]), ("distance", panel["distance"])):
        success[name] = {c: seed_statistics(rates[c]) for c in CONDITIONS}
    for variant, rates in found.items():
        success[variant] = {c: seed_statistics(rates[c]) for c in CONDITIONS}
        for other in ("independent", "distance"):
            differences[f"{variant}-{other}"] = {
                c: paired(list(np.subtract(rates[c], panel[other][c]))) for c in CONDITIONS
            }
    return {"map_seed": map_seed, "success": success, "differences": differences, "panel": source}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    use_reproducible_matmul()  # before the first matrix product
    make_console_safe()
    args = why.parse_args(argv, __doc__.split("\n\n")[0], "train both variants' batches first")
    if args.train:
        why.train_batches(VARIANTS, MODE, CLOCK_DIR, args.workers)
    torch.set_num_threads(1)
    maps = {}
    for map_seed in MAPS:
        entry = measure_map(map_seed, args.num_episodes)
        maps[str(map_seed)] = entry
        print(
            f"map {map_seed}: "
            + ", ".join(f"{k} {v['eps']['mean']:.3f}" for k, v in entry["success"].items())
        )
    results = {
        "description": __doc__.split("\n\n")[0],
        "protocol": {
            "maps": list(MAPS),
            "mode": MODE,
            "training_seeds": list(SEEDS),
            "episodes_per_seed": args.num_episodes,
            "conditions": CONDITIONS,
            "evaluation_seed": EVAL_SEED,
            "variants": {
                "clock": "element 10 = step of the episode / max_steps, in training and test",
                "noise": f"element 10 = uniform [0, 1) per copy and step (seed {NOISE_SEED})",
            },
        },
        "maps": maps,
    }
    CLOCK_DIR.mkdir(parents=True, exist_ok=True)
    write_json_atomic(CLOCK_DIR / "clock.json", results)
    print(f"wrote {CLOCK_DIR / 'clock.json'}")
    return results


if __name__ == "__main__":
    run_command(main)
