"""The clock control (studies/one_step/clock.py): the distance element replaced by the step of
the episode or by noise, everything else of the observation unchanged, in the observations
returned, in ``final_obs`` and after a copy restarts."""

from __future__ import annotations

import numpy as np
import pytest
from studies.one_step.clock import ClockEnv, NoiseEnv
from vector_env import DISTANCE_INDEX as DISTANCE
from vector_env import VectorMultiAgentEnv

STAY = 4


def play(env: VectorMultiAgentEnv, steps: int) -> list[tuple]:
    """Every copy stays put for ``steps`` steps; the step results, reset's observations first."""
    found = [(env.reset(seed=3), None)]
    for t in range(steps):
        messages = np.full((env.n_envs, 2), 0.1 * (t + 1))
        obs, _, _, _, info = env.step(np.full((env.n_envs, 2), STAY), messages)
        found.append((obs, info))
    return found


@pytest.mark.parametrize("env_class", [ClockEnv, NoiseEnv])
def test_only_the_distance_element_differs_from_the_plain_env(env_class: type) -> None:
    plain, replaced = (
        play(VectorMultiAgentEnv(4, seed=2, max_steps=4), 6),
        play(env_class(4, seed=2, max_steps=4), 6),
    )
    for (obs, info), (obs_r, info_r) in zip(plain, replaced, strict=True):
        others = [k for k in range(obs.shape[-1]) if k != DISTANCE]
        np.testing.assert_array_equal(obs[..., others], obs_r[..., others])
        if info is not None:
            np.testing.assert_array_equal(info["positions"], info_r["positions"])
        assert ((obs_r[..., DISTANCE] >= 0) & (obs_r[..., DISTANCE] <= 1)).all()


def test_the_clock_reads_the_step_over_the_limit_and_restarts_at_zero() -> None:
    results = play(ClockEnv(3, seed=2, max_steps=4), 5)
    assert not results[0][0][..., DISTANCE].any()  # an episode starts at step 0
    for t, (obs, info) in enumerate(results[1:], start=1):
        step = t % 4  # staying put, every copy is cut off at step 4 and restarts
        np.testing.assert_allclose(obs[..., DISTANCE], step / 4)
        np.testing.assert_allclose(
            info["final_obs"][..., DISTANCE], np.repeat((info["steps"] / 4)[:, None], 2, axis=1)
        )
        assert (obs[:, 0, DISTANCE] == obs[:, 1, DISTANCE]).all()


def test_the_noise_is_fresh_each_step_shared_by_a_copys_agents_and_reproducible() -> None:
    first, again = play(NoiseEnv(5, seed=2), 3), play(NoiseEnv(5, seed=2), 3)
    values = np.array([obs[..., DISTANCE] for obs, _ in first])
    np.testing.assert_array_equal(values, [obs[..., DISTANCE] for obs, _ in again])
    assert (values[..., 0] == values[..., 1]).all()
    assert len(np.unique(values[..., 0])) == values[..., 0].size  # no value repeats
