"""Training on a pool of generated maps: the extensions of the core learner that the map-pool
and memory studies use, none of them part of the assignment's recipe.

* :class:`PoolConfig`: :class:`~settings.TrainConfig` with the pool's settings (the pool
  size, validation maps, parameter sharing, the coverage and on-target bonuses).
* :class:`PooledVectorEnv`: the vectorised environment whose copies draw a map from the pool
  at every episode start, and which can count the grid cells the agents have seen.
* :class:`PoolTrainer`: the core learner (:class:`~trainer.DQNTrainer`) on such
  environments (validated on other generated maps), with the bonuses added to the learning
  reward and, with ``share_weights``, one set of weights for both agents.
* :func:`study_parser`: the command-line flags those two studies share.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from analysis.map_sets import MAX_POOL_SIZE, training_maps, validation_maps
from settings import NON_NEGATIVE, TrainConfig, available_cores, boolean, int_in, setting
from trainer import DQNTrainer
from vector_env import (
    FREE,
    OBSTACLE,
    OFF_GRID,
    TARGET,
    VectorMultiAgentEnv,
    check_grid,
    reaches_target,
)


def check_grid_stack(maps: np.ndarray, name: str = "maps") -> np.ndarray:
    """``maps`` (M, H, W) as a read-only int64 stack, or ValueError naming the first bad
    map: what :func:`check_grid` checks, vectorised over the stack."""
    maps = np.asarray(maps)
    if maps.ndim != 3 or len(maps) == 0 or maps.dtype.kind not in "iu":
        raise ValueError(
            f"{name} must be a non-empty integer stack of maps (M, H, W), got "
            f"{maps.dtype} {maps.shape}"
        )
    well_formed = (
        ((maps == FREE) | (maps == OBSTACLE) | (maps == TARGET)).all(axis=(1, 2))
        & ((maps == TARGET).sum(axis=(1, 2)) == 1)
        & ((maps == FREE).sum(axis=(1, 2)) >= 2)
        & (reaches_target(maps) | (maps == OBSTACLE)).all(axis=(1, 2))
    )
    if not well_formed.all():
        index = int(np.argmin(well_formed))
        try:
            check_grid(maps[index])  # names the problem
        except ValueError as error:
            raise ValueError(f"{name}[{index}]: {error}") from error
    check_grid(maps[0])  # the size rules
    stack = maps.astype(np.int64)
    stack.flags.writeable = False
    return stack


@dataclass
class PoolConfig(TrainConfig):
    """The core settings and those of training on a map pool."""

    map_pool: int = setting(0, int_in(0, MAX_POOL_SIZE))
    """0: train on the --map_seed map; N > 0: on a pool of N generated maps (analysis/map_sets.py),
    a new one drawn at each episode start, evaluated on other generated maps"""
    validation_maps: int = setting(200, int_in(1, MAX_POOL_SIZE))
    """with --map_pool: generated validation maps of the periodic evaluations (1 or more)"""
    share_weights: bool = setting(False, boolean)
    """parameter sharing: both agents use one set of weights (same start, summed gradient), a
    departure from the assignment's independent learners"""
    coverage_bonus: float = setting(0.0, NON_NEGATIVE)
    """reward shaping for learning only (>= 0): added per grid cell that enters either agent's 3x3
    view for the first time in the episode"""
    on_target_bonus: float = setting(0.0, NON_NEGATIVE)
    """reward shaping for learning only (>= 0): added per agent standing on the target"""


class PooledVectorEnv(VectorMultiAgentEnv):
    """``n_envs`` copies on several maps: with ``map_pool`` (M, H, W) each copy draws a map
    uniformly at each episode start (from the same stream as the start cells, map first);
    with ``grids`` (N, H, W) copy i plays map i for its lifetime. With ``track_coverage`` each
    step's ``info`` holds ``newly_seen`` (N,) int64: the grid cells that entered either agent's
    patch for the first time in the episode. Other arguments as the core environment's."""

    def __init__(
        self,
        n_envs: int,
        *,
        map_pool: np.ndarray | None = None,
        grids: np.ndarray | None = None,
        track_coverage: bool = False,
        **kwargs: Any,
    ) -> None:
        chosen = (("grid", kwargs.get("grid")), ("map_pool", map_pool), ("grids", grids))
        given = [name for name, value in chosen if value is not None]
        if len(given) > 1:
            raise ValueError(f"give one of grid, map_pool and grids, got {' and '.join(given)}")
        self._pool = None if map_pool is None else check_grid_stack(map_pool, "map_pool")
        self._fixed = None if grids is None else check_grid_stack(grids, "grids")
        if self._fixed is not None and len(self._fixed) != n_envs:
            raise ValueError(f"grids must hold n_envs = {n_envs} maps, got {len(self._fixed)}")
        self.track_coverage = bool(track_coverage)
        super().__init__(n_envs, **kwargs)

    def _choose_maps(self, grid_size, seed, grid):  # noqa: ANN001, ANN202
        maps = self._pool if self._fixed is None else self._fixed
        if maps is None:
            return super()._choose_maps(grid_size, seed, grid)
        return maps, maps[0] if len(maps) == 1 else None

    @property
    def map_indices(self) -> np.ndarray:
        """Index (N,) int64 into ``grids`` of the map each copy plays now."""
        return self._map_index.copy()

    @property
    def target_positions(self) -> np.ndarray:
        """Target cell (N, 2) of each copy's current map."""
        return self._rows_cols(self._copy_target)

    def _assign_maps(self, rows: np.ndarray, maps: np.ndarray) -> None:
        self._map_index[rows] = maps
        self._copy_base[rows] = maps * self._cells_per_map
        self._copy_target[rows] = self._target_flat[maps]

    def _before_placement(self, rows: np.ndarray) -> None:
        """Give copies ``rows`` a uniformly drawn map each (or, with ``grids``, their own)."""
        if self._pool is not None:
            self._assign_maps(
                rows, (self._rng.random(len(rows)) * len(self.grids)).astype(np.int64)
            )
        elif self._fixed is not None:
            self._assign_maps(rows, rows)

    def _build_lookup_tables(self) -> None:
        super()._build_lookup_tables()
        if self.track_coverage:  # the cells each copy has seen in its episode, and how many
            # Padding cells count as seen from the start: only grid cells can be new.
            self._off_grid = self._cell_values[: self._cells_per_map] == OFF_GRID  # (P,)
            self._seen = np.zeros((self.n_envs, self._cells_per_map), dtype=bool)
            self._seen_count = np.zeros(self.n_envs, dtype=np.int64)

    def _start_episodes(self, rows: np.ndarray, flat: np.ndarray | None = None) -> None:
        super()._start_episodes(rows, flat)
        if self.track_coverage:
            self._seen[rows] = self._off_grid
            self._mark_seen(rows)

    def _after_move(self, info: dict[str, np.ndarray]) -> None:
        if self.track_coverage:
            info["newly_seen"] = self._mark_seen(slice(None))

    def _mark_seen(self, rows: np.ndarray | slice) -> np.ndarray:
        """Mark both agents' patch cells as seen in copies ``rows``; return how many were new."""
        local = self._flat[rows] - self._copy_base[rows, None]  # (n, 2)
        patch_cells = (local[:, :, None] + self._patch_offsets).reshape(len(local), -1)
        seen = self._seen[rows]
        np.put_along_axis(seen, patch_cells, True, axis=1)
        self._seen[rows] = seen
        counts = seen.sum(axis=1)
        newly_seen = counts - self._seen_count[rows]
        self._seen_count[rows] = counts
        return newly_seen


class CurriculumEnv(PooledVectorEnv):
    """The vectorised environment, except that a share ``start_on_target`` (0 unless set)
    of the episodes it starts by itself begin with one agent, A or B at random, on the
    target (a reverse curriculum, Florensa et al. 2017: the goal is first met from states
    next to it): the other agent's start cell is drawn as usual, and that agent counts as
    having arrived (no arrival reward for it; the cells it sees count as seen). Trainers set
    the share on their training copies only; validation and test episodes start as the
    task's do."""

    start_on_target: float = 0.0

    def _start_episodes(self, rows: np.ndarray, flat: np.ndarray | None = None) -> None:
        super()._start_episodes(rows, flat)
        if flat is not None or self.start_on_target <= 0 or not len(rows):
            return
        draws = self._rng.random((len(rows), 2))
        target = self._copy_target[rows]
        starts = self._flat[rows].copy()  # (n, 2)
        chosen = (draws[:, 0] < self.start_on_target) & (starts != target[:, None]).all(axis=1)
        if not chosen.any():
            return
        agent = (draws[chosen, 1] < 0.5).astype(np.int64)  # 1: B stands on the target
        starts = starts[chosen]
        starts[np.arange(len(starts)), agent] = target[chosen]
        super()._start_episodes(rows[chosen], starts)


class PoolTrainer(DQNTrainer):
    """The core learner on a map pool (``cfg`` a :class:`PoolConfig`), with the pool's
    shaping and optional parameter sharing."""

    vector_env_class: type[PooledVectorEnv] = PooledVectorEnv

    def __init__(self, env: Any, args: PoolConfig) -> None:
        if not isinstance(args, PoolConfig):
            raise TypeError(f"PoolTrainer trains from a PoolConfig, got {type(args).__name__}")
        super().__init__(env, args)
        if self.cfg.share_weights:  # one set of weights: B starts as a copy of A
            with torch.no_grad():
                for parameter in self.online.parameters():  # agent axis first
                    parameter[1] = parameter[0]
            self.target.load_state_dict(self.online.state_dict())

    def make_vector_env(
        self, n_envs: int, seed: int | None, validation: bool = False
    ) -> VectorMultiAgentEnv:
        """With ``map_pool`` > 0, copies that draw from the training maps (tracking the cells
        seen, for the coverage bonus) or, for ``validation``, from the validation maps."""
        cfg = self.cfg
        if not cfg.map_pool:
            return super().make_vector_env(n_envs, seed, validation)
        size = self.env.grid_size
        pool = validation_maps(cfg.validation_maps, size) if validation else None
        return self.vector_env_class(
            n_envs,
            map_pool=training_maps(cfg.map_pool, size) if pool is None else pool,
            track_coverage=not validation and cfg.coverage_bonus > 0,
            obs_window=self.env.obs_window,
            max_steps=self.env.max_steps,
            seed=seed,
            reward_mode=cfg.reward_mode,
        )

    def learning_rewards(
        self, rewards: np.ndarray, info: dict[str, np.ndarray], obs: np.ndarray
    ) -> np.ndarray:
        """The core's learning reward, plus ``on_target_bonus`` per agent on the target and
        ``coverage_bonus`` per newly seen cell."""
        rewards = super().learning_rewards(rewards, info, obs)
        if self.cfg.on_target_bonus > 0:
            rewards = rewards + self.cfg.on_target_bonus * info["on_target"].sum(axis=1)
        if self.cfg.coverage_bonus > 0 and "newly_seen" in info:
            rewards = rewards + self.cfg.coverage_bonus * info["newly_seen"]
        return rewards

    def after_backward(self) -> None:
        """With ``share_weights``, each shared parameter gets the sum of both agents' gradients."""
        if self.cfg.share_weights:
            for p in self.online_parameters:  # each (2, ...), agent axis first
                if p.grad is not None:  # None: a message head no loss reaches (independent)
                    p.grad.copy_(p.grad.sum(dim=0, keepdim=True).expand_as(p.grad))


def study_parser(
    description: str,
    recipe: dict[str, Any],
    modes: tuple[str, ...],
    default_dir: Path,
    stem: str,
    with_map_pool: bool = False,
) -> argparse.ArgumentParser:
    """The flags of a study on the map pool (``map_pool_study``, the memory study): defaults from
    ``recipe``; ``--map_pool`` if ``with_map_pool``; ``--plot_only`` redraws ``<stem>.png``
    from ``<stem>.json``."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        description=description,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add = parser.add_argument
    add(
        "--total_steps",
        "--total-steps",
        type=int,
        default=recipe["total_steps"],
        help="environment steps per run",
    )
    add(
        "--num_seeds",
        "--num-seeds",
        type=int,
        default=len(recipe["seeds"]),
        help="training seeds per mode (seeds 0, 1, ...)",
    )
    add("--mode", default="all", help="all, or a comma-separated list of " + ", ".join(modes))
    if with_map_pool:
        add(
            "--map_pool",
            "--map-pool",
            type=int,
            default=recipe["map_pool"],
            help=f"training maps (1..{MAX_POOL_SIZE})",
        )
    add(
        "--episodes_per_map",
        "--episodes-per-map",
        type=int,
        default=500,
        help="test episodes per held-out map and condition (1..100000)",
    )
    add("--workers", type=int, default=available_cores(), help="parallel training processes")
    add(
        "--output_dir",
        "--output-dir",
        type=Path,
        default=default_dir,
        help="folder written (relative: to the current folder)",
    )
    add(
        "--plot_only",
        "--plot-only",
        action="store_true",
        help=f"only redraw {stem}.png from the {stem}.json in --output_dir (no training)",
    )
    return parser
