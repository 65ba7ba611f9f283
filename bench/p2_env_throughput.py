"""Problem 2 environment throughput: env-steps per second with random actions.

Compares ``MultiAgentEnv`` stepped in a Python loop with ``VectorMultiAgentEnv`` at
N = 1, 16, 64, 256, 1024 copies (the default 10×10 map, seed 641). Actions and messages
are drawn before timing, so the figures measure the environment alone; one env-step is
one joint step of one copy. Target: ≥ 1 M env-steps/s at N = 256 on one core.

Usage: python bench/p2_env_throughput.py [--seconds 1.0]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "problem2"))
from multi_agent_env import MultiAgentEnv
from vector_env import DEFAULT_MAP_SEED, VectorMultiAgentEnv

VECTOR_SIZES = (1, 16, 64, 256, 1024)
PREDRAWN = 64  # distinct action/message arrays cycled through


def single_env_rate(seconds: float) -> tuple[float, float]:
    """(env-steps/s, µs per step call) of MultiAgentEnv, resetting when done."""
    env = MultiAgentEnv(seed=DEFAULT_MAP_SEED)
    rng = np.random.default_rng(0)
    actions = rng.integers(5, size=(PREDRAWN, 2)).tolist()
    messages = rng.random((PREDRAWN, 2)).tolist()
    env.reset()
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for (action_a, action_b), (comm_a, comm_b) in zip(actions, messages, strict=True):
            _, _, done = env.step(action_a, action_b, comm_a, comm_b)
            if done:
                env.reset()
        steps += PREDRAWN
    elapsed = time.perf_counter() - start
    return steps / elapsed, elapsed / steps * 1e6


def vector_env_rate(n_envs: int, seconds: float) -> tuple[float, float]:
    """(env-steps/s, µs per step call) of VectorMultiAgentEnv with ``n_envs`` copies."""
    env = VectorMultiAgentEnv(n_envs, seed=DEFAULT_MAP_SEED)
    rng = np.random.default_rng(0)
    actions = rng.integers(5, size=(PREDRAWN, n_envs, 2))
    messages = rng.random((PREDRAWN, n_envs, 2))
    env.reset()
    calls, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for action, message in zip(actions, messages, strict=True):
            env.step(action, message)
        calls += PREDRAWN
    elapsed = time.perf_counter() - start
    return calls * n_envs / elapsed, elapsed / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="time per row")
    args = parser.parse_args()
    rows = [("MultiAgentEnv loop", 1, *single_env_rate(args.seconds))]
    rows += [("VectorMultiAgentEnv", n, *vector_env_rate(n, args.seconds)) for n in VECTOR_SIZES]
    print(f"{'environment':<20} {'N':>5} {'env-steps/s':>12} {'µs per call':>12}")
    for name, n_envs, rate, micros in rows:
        print(f"{name:<20} {n_envs:>5} {rate:>12,.0f} {micros:>12.1f}")


if __name__ == "__main__":
    main()
