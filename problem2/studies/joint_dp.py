"""Exact dynamic programming over the joint positions of both agents, with full information.

What does each reward ask for, independent of learning? A state is (cell of A, cell of B,
A has reached the target this episode, B has) — the two flags matter only to the arrival
reward, which pays its bonus on an agent's first arrival. Moves are the environment's: a
move into a wall or an obstacle stays, agents may share a cell, both on the target ends the
episode. Two problems are solved for each reward, both with discount ``gamma``:

* ``finite_horizon``: the episode as it is, 50 steps, time in the state (backward pass).
* ``stationary``: no clock, the infinite-horizon discounted problem. This is what the
  trainer's TD target optimises, since it bootstraps through the 50-step cut-off and the
  agents do not observe time; its policy is rolled out for 50 steps.

Team rewards, one value per step (:func:`team_reward`, the single definition used here and
by ``reward_study.py``): ``per_step`` (the assignment's table) pays +10 when both agents
stand on the target (terminal), +2 on every step on which exactly one stands on it, -0.1
otherwise; ``arrival`` pays +10 when both stand on the target, +2 on the step on which an
agent first reaches the target in the episode, -0.1 otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from analysis.episodes import target_distances
from vector_env import (
    ACTION_DELTAS,
    ARRIVAL_REWARD,
    BOTH_ON_TARGET_REWARD,
    NUM_ACTIONS,
    OBSTACLE,
    STEP_REWARD,
    TARGET,
)

REWARDS = ("per_step", "arrival")
GAMMA = 0.99
HORIZON = 50
NUM_JOINT_ACTIONS = NUM_ACTIONS**2  # joint action j = 5 * action_A + action_B


def check_reward(reward: str) -> str:
    if reward not in REWARDS:
        raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
    return reward


def team_reward(
    reward: str, on_target: np.ndarray, visited: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Team reward and termination of a step, (...) float64 and (...) bool.

    ``on_target`` (..., 2): each agent stands on the target after the step; ``visited``
    (..., 2): it had stood on it earlier in the episode (its start cell included)."""
    check_reward(reward)
    both = on_target[..., 0] & on_target[..., 1]
    pays = on_target if reward == "per_step" else on_target & ~visited
    bonus = pays[..., 0] | pays[..., 1]
    rewards = np.where(both, BOTH_ON_TARGET_REWARD, np.where(bonus, ARRIVAL_REWARD, STEP_REWARD))
    return rewards, both


def step_rewards_from_positions(
    positions: np.ndarray, lengths: np.ndarray, target: tuple[int, int], reward: str
) -> np.ndarray:
    """Reward (E, T) of each step of recorded episodes, 0 after an episode's end.

    ``positions`` (E, T + 1, 2, 2): cells (row, col) before each step and after the last;
    ``lengths`` (E,): steps taken in each episode."""
    on_target = (positions == np.asarray(target)).all(axis=-1)  # (E, T + 1, 2)
    visited_before = np.logical_or.accumulate(on_target, axis=1)[:, :-1]
    rewards, _ = team_reward(reward, on_target[:, 1:], visited_before)
    steps = np.arange(1, positions.shape[1])
    return np.where(steps[None, :] <= np.asarray(lengths)[:, None], rewards, 0.0)


def returns_from_positions(
    positions: np.ndarray,
    lengths: np.ndarray,
    target: tuple[int, int],
    reward: str,
    gamma: float = 1.0,
) -> np.ndarray:
    """Return (E,) of recorded episodes under ``reward``, discounted by ``gamma`` (the
    environment's episode return for gamma = 1). Shapes as in step_rewards_from_positions."""
    rewards = step_rewards_from_positions(positions, lengths, target, reward)
    return rewards @ gamma ** np.arange(rewards.shape[1], dtype=np.float64)


@dataclass(frozen=True)
class JointSpace:
    """Passable cells of a map and the joint states built on them.

    State index s = ((a * n + b) * 2 + visited_A) * 2 + visited_B for cells a, b in 0..n-1.
    """

    grid: np.ndarray  # (H, W) int: 0 free, 1 obstacle, 2 target
    cells: np.ndarray  # (n, 2) (row, col) of every passable cell, row-major
    next_cell: np.ndarray  # (n, 5) cell reached by each action
    target: int  # index of the target cell

    @property
    def num_cells(self) -> int:
        return len(self.cells)

    @property
    def num_states(self) -> int:
        return self.num_cells**2 * 4

    def state_index(
        self, cell_a: np.ndarray, cell_b: np.ndarray, visited_a: np.ndarray, visited_b: np.ndarray
    ) -> np.ndarray:
        """Flat state indices, same shape as the (broadcast) inputs."""
        n = self.num_cells
        return ((np.asarray(cell_a) * n + cell_b) * 2 + visited_a) * 2 + visited_b

    def decode(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(cell_A, cell_B, visited_A, visited_B), each shaped as ``states``."""
        states = np.asarray(states)
        pair, visited_b = np.divmod(states, 2)
        pair, visited_a = np.divmod(pair, 2)
        cell_a, cell_b = np.divmod(pair, self.num_cells)
        return cell_a, cell_b, visited_a.astype(bool), visited_b.astype(bool)

    def cell_index(self, row: int, col: int) -> int:
        found = np.flatnonzero((self.cells == (row, col)).all(axis=1))
        if found.size == 0:
            raise ValueError(f"cell ({row}, {col}) is off the grid or an obstacle")
        return int(found[0])

    def start_states(self) -> np.ndarray:
        """States (P,) of every ordered pair of distinct free non-target cells, both flags
        clear: the starts ``env.reset`` draws, each equally likely."""
        free = np.flatnonzero(self.grid[self.cells[:, 0], self.cells[:, 1]] != TARGET)
        cell_a, cell_b = np.meshgrid(free, free, indexing="ij")
        distinct = cell_a != cell_b
        return self.state_index(cell_a[distinct], cell_b[distinct], 0, 0)


def build_joint_space(grid: np.ndarray) -> JointSpace:
    """Joint space of ``grid`` (H, W) with values 0 free, 1 obstacle, 2 one target (any
    size, so tiny corridors serve as tests)."""
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.dtype.kind not in "iu" or not np.isin(grid, (0, 1, 2)).all():
        raise ValueError("grid must be a 2-D integer array of 0 free, 1 obstacle, 2 target")
    if (grid == TARGET).sum() != 1:
        raise ValueError(f"grid must hold exactly one target, found {(grid == TARGET).sum()}")
    cells = np.argwhere(grid != OBSTACLE)
    index = np.full(grid.shape, -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    moved = cells[:, None, :] + ACTION_DELTAS[None, :, :]  # (n, 5, 2)
    inside = ((moved >= 0) & (moved < grid.shape)).all(axis=-1)
    clipped = np.clip(moved, 0, np.array(grid.shape) - 1)
    landing = index[clipped[..., 0], clipped[..., 1]]
    next_cell = np.where(inside & (landing >= 0), landing, np.arange(len(cells))[:, None])
    target = int(index[tuple(np.argwhere(grid == TARGET)[0])])
    return JointSpace(grid, cells, next_cell, target)


@dataclass(frozen=True)
class Transitions:
    """Deterministic joint transitions (S, 25): next state, team reward, termination."""

    next_state: np.ndarray
    reward: np.ndarray
    terminal: np.ndarray


def build_transitions(space: JointSpace, reward: str) -> Transitions:
    cell_a, cell_b, visited_a, visited_b = space.decode(np.arange(space.num_states))
    joint = np.arange(NUM_JOINT_ACTIONS)
    next_a = space.next_cell[cell_a[:, None], joint[None, :] // NUM_ACTIONS]  # (S, 25)
    next_b = space.next_cell[cell_b[:, None], joint[None, :] % NUM_ACTIONS]
    on_target = np.stack((next_a == space.target, next_b == space.target), axis=-1)
    visited = np.stack((visited_a, visited_b), axis=-1)[:, None, :]
    rewards, terminal = team_reward(reward, on_target, visited)
    now_visited = visited | on_target
    next_state = space.state_index(next_a, next_b, now_visited[..., 0], now_visited[..., 1])
    return Transitions(next_state, rewards, terminal)


def with_potential_shaping(
    transitions: Transitions, potential: np.ndarray, gamma: float = GAMMA
) -> Transitions:
    """Add Ng, Harada & Russell's (1999) shaping term gamma * potential(s') - potential(s)
    (potential (S,); 0 after a terminal step). In the stationary problem this provably keeps
    the optimal policies; the optimal values become V*(s) - potential(s)."""
    rows = np.arange(len(transitions.next_state))[:, None]
    following = np.where(transitions.terminal, 0.0, potential[transitions.next_state])
    shaped = transitions.reward + gamma * following - potential[rows]
    return Transitions(transitions.next_state, shaped, transitions.terminal)


def distance_potential(space: JointSpace, scale: float = 1.0) -> np.ndarray:
    """Potential (S,) = -scale * (path distance of A + of B to the target): the shaping
    one would add to pull both agents onto the target."""
    distance = target_distances(space.grid)[space.cells[:, 0], space.cells[:, 1]]
    cell_a, cell_b, _, _ = space.decode(np.arange(space.num_states))
    return -scale * (distance[cell_a] + distance[cell_b])


@dataclass(frozen=True)
class Solution:
    """Optimal values and greedy joint actions. Finite horizon: values (T + 1, S) with
    values[t] the optimum from step t, policy (T, S); stationary: values (1, S), policy
    (1, S) used at every step."""

    values: np.ndarray
    policy: np.ndarray
    stationary: bool


def _backup(transitions: Transitions, gamma: float, next_values: np.ndarray) -> np.ndarray:
    """Action values (S, 25) given the values of the next step (S,)."""
    future = np.where(transitions.terminal, 0.0, next_values[transitions.next_state])
    return transitions.reward + gamma * future


def solve_finite_horizon(
    transitions: Transitions, gamma: float = GAMMA, horizon: int = HORIZON
) -> Solution:
    """Backward pass over ``horizon`` steps (a loop over time, vectorised over states)."""
    num_states = len(transitions.next_state)
    values = np.zeros((horizon + 1, num_states))
    policy = np.zeros((horizon, num_states), dtype=np.int8)
    for t in range(horizon - 1, -1, -1):
        q_values = _backup(transitions, gamma, values[t + 1])
        policy[t] = q_values.argmax(axis=1)
        values[t] = np.take_along_axis(q_values, policy[t, :, None].astype(np.int64), 1)[:, 0]
    return Solution(values, policy, stationary=False)


def solve_stationary(
    transitions: Transitions, gamma: float = GAMMA, tolerance: float = 1e-9
) -> Solution:
    """Infinite-horizon discounted optimum by modified policy iteration: greedy policy,
    then cheap sweeps of that policy's own Bellman operator, until a full backup changes
    no value by more than ``tolerance`` (then ‖V - V*‖∞ ≤ tolerance·γ/(1 − γ))."""
    if not 0 < gamma < 1:
        raise ValueError(f"the stationary problem needs 0 < gamma < 1, got {gamma}")
    rows = np.arange(len(transitions.next_state))
    # Start below V* (T V >= V there), where modified policy iteration converges monotonically.
    values = np.full(len(rows), min(transitions.reward.min(), 0.0) / (1 - gamma))
    while True:
        q_values = _backup(transitions, gamma, values)
        policy = q_values.argmax(axis=1)
        new_values = q_values[rows, policy]
        if np.abs(new_values - values).max() <= tolerance:
            return Solution(new_values[None], policy[None].astype(np.int8), stationary=True)
        values = new_values
        next_state = transitions.next_state[rows, policy]
        continues = ~transitions.terminal[rows, policy]
        reward = transitions.reward[rows, policy]
        for _ in range(100):  # evaluation sweeps of the fixed policy: S work each, not 25 S
            values = reward + gamma * np.where(continues, values[next_state], 0.0)


@dataclass(frozen=True)
class Rollout:
    """Greedy episodes of a solution from start states (P,): positions (P, T + 1, 2, 2) as
    recorded by ``rollout.run_episodes`` (held after the end), lengths and successes (P,)."""

    positions: np.ndarray
    lengths: np.ndarray
    successes: np.ndarray


def roll_out(
    space: JointSpace,
    transitions: Transitions,
    solution: Solution,
    start_states: np.ndarray,
    horizon: int = HORIZON,
) -> Rollout:
    """Follow the greedy joint policy deterministically for at most ``horizon`` steps."""
    states = np.array(start_states, dtype=np.int64)
    count = len(states)
    cells = np.zeros((count, horizon + 1, 2), dtype=np.int64)
    cells[:, 0] = np.stack(space.decode(states)[:2], axis=-1)
    lengths = np.full(count, horizon, dtype=np.int64)
    successes = np.zeros(count, dtype=bool)
    active = np.ones(count, dtype=bool)
    for t in range(horizon):
        actions = solution.policy[0 if solution.stationary else t, states].astype(np.int64)
        terminal = transitions.terminal[states, actions] & active
        states = np.where(active, transitions.next_state[states, actions], states)
        cells[:, t + 1] = np.stack(space.decode(states)[:2], axis=-1)
        successes |= terminal
        lengths[terminal] = t + 1
        active &= ~terminal
    return Rollout(space.cells[cells], lengths, successes)


def optimal_values(solution: Solution, start_states: np.ndarray) -> np.ndarray:
    """Optimal discounted value (P,) of each start state at t = 0."""
    return solution.values[0, start_states]
