"""Figures for Problem 1: value heatmap with policy arrows, policy, Q-functions, convergence.

python visualize.py    # redraws the figures from the .npz files that train.py wrote
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from environment import ACTION_NAMES, MOVES, GridWorldEnv
from file_io import atomic_save_figure
from matplotlib.axes import Axes
from matplotlib.figure import Figure  # figures without pyplot: no GUI backend, no global state
from matplotlib.patches import Rectangle

RESULTS_DIR = Path(__file__).resolve().parent / "results"
CELL_STYLE = {  # edge colour and label of the special cells
    "goal": ("#1a9641", "GOAL +10"),
    "penalty": ("#d7191c", "PENALTY −5"),
    "start": ("#2b83ba", "START"),
}


class GridWorldVisualizer:
    """Draws gridworld results; the layout comes from ``env`` (the course map by default)."""

    def __init__(self, grid_size: int = 5, env: GridWorldEnv | None = None) -> None:
        self.env = env if env is not None else GridWorldEnv()
        if self.env.grid_size != grid_size:
            raise ValueError(
                f"grid_size {grid_size} does not match the layout "
                f"({self.env.grid_size}x{self.env.grid_size})"
            )
        self.grid_size = grid_size
        self.n_states = grid_size * grid_size
        # cells without a decision: obstacles and the terminal goal (their value is fixed at 0)
        self.absorbing_cells = self.env._blocked.copy()
        self.absorbing_cells[self.env.goal_pos] = True

    # ------------------------------------------------------------------ building blocks
    def draw_grid(
        self,
        ax: Axes,
        values: np.ndarray | None = None,
        policy: np.ndarray | None = None,
        title: str = "",
        annotate: bool = True,
        vmin: float | None = None,
        vmax: float | None = None,
    ):
        """Draw one grid on ``ax``: optional value heatmap (S,), optional arrows (S,).

        Obstacles are black, the goal, penalty and start cells are framed and labelled.
        Returns the image of the heatmap (for a colour bar), or None.
        """
        n = self.grid_size
        image = None
        if values is not None:
            grid = np.ma.masked_array(
                np.asarray(values, dtype=float).reshape(n, n), mask=self.absorbing_cells
            )
            image = ax.imshow(grid, cmap="viridis", vmin=vmin, vmax=vmax)
            if annotate:
                self._annotate_values(ax, grid, image)
        else:
            ax.imshow(np.zeros((n, n)), cmap="Greys", vmin=0, vmax=1)
        for r, c in self.env.obstacles:
            ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, color="black"))
        goal_r, goal_c = self.env.goal_pos
        ax.add_patch(Rectangle((goal_c - 0.5, goal_r - 0.5), 1, 1, color="#a6d96a"))
        special = [
            ("goal", [self.env.goal_pos]),
            ("penalty", self.env.penalties),
            ("start", [self.env.start_pos]),
        ]
        for kind, cells in special:
            colour, label = CELL_STYLE[kind]
            for r, c in cells:
                ax.add_patch(
                    Rectangle(
                        (c - 0.46, r - 0.46), 0.92, 0.92, fill=False, edgecolor=colour, linewidth=3
                    )
                )
                ax.text(
                    c,
                    r - 0.36,
                    label,
                    ha="center",
                    va="center",
                    fontsize=6,
                    color=colour,
                    fontweight="bold",
                    bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5},
                )
        if policy is not None:
            self._draw_arrows(ax, np.asarray(policy), shift=0.2 if values is not None else 0.0)
        ax.set_xticks(range(n))
        ax.set_yticks(range(n))
        ax.set_xlabel("column")
        ax.set_ylabel("row")
        ax.set_title(title)
        return image

    def _annotate_values(self, ax: Axes, grid: np.ma.MaskedArray, image) -> None:
        for (r, c), value in np.ndenumerate(grid.filled(np.nan)):
            if np.isnan(value):
                continue
            brightness = np.mean(image.cmap(image.norm(value))[:3])
            ax.text(
                c,
                r - 0.17,
                f"{value:.2f}",
                ha="center",
                va="center",
                fontsize=8,
                color="black" if brightness > 0.5 else "white",
            )

    def _draw_arrows(self, ax: Axes, policy: np.ndarray, shift: float) -> None:
        """One arrow per decision state (not the goal, not obstacles)."""
        for state, action in enumerate(policy.reshape(-1)):
            r, c = divmod(state, self.grid_size)
            if self.absorbing_cells[r, c]:
                continue
            dr, dc = MOVES[int(action)]
            ax.annotate(
                "",
                xy=(c + 0.25 * dc, r + shift + 0.2 * dr),
                xytext=(c - 0.15 * dc, r + shift - 0.1 * dr),
                arrowprops={"arrowstyle": "-|>", "color": "#f03b20", "lw": 2},
            )

    # ------------------------------------------------------------------ figures
    def plot_value_function(
        self,
        values: np.ndarray,
        title: str = "Optimal state values V*",
        policy: np.ndarray | None = None,
    ) -> Figure:
        """Heatmap of ``values`` (S,) with the value in each cell and optional policy arrows."""
        fig = Figure(figsize=(6.4, 5.6))
        ax = fig.subplots()
        image = self.draw_grid(ax, values, policy, title)
        fig.colorbar(image, ax=ax, label="V(s)  (expected discounted return)")
        return fig

    def plot_policy(self, policy: np.ndarray, title: str = "Optimal policy") -> Figure:
        """Arrows of a deterministic policy (S,) on the map."""
        fig = Figure(figsize=(5.4, 5.4))
        ax = fig.subplots()
        self.draw_grid(ax, None, policy, title)
        return fig

    def plot_q_function(
        self, q_values: np.ndarray, title: str = "Optimal action values Q*(s, a)"
    ) -> Figure:
        """Four heatmaps, one per action, of ``q_values`` (S, 4) on a shared colour scale."""
        q_values = np.asarray(q_values, dtype=float)
        decision = ~self.absorbing_cells.reshape(-1)
        vmin, vmax = q_values[decision].min(), q_values[decision].max()
        fig = Figure(figsize=(10, 9), layout="constrained")
        axes = fig.subplots(2, 2)
        for action, ax in enumerate(axes.flat):
            image = self.draw_grid(
                ax,
                q_values[:, action],
                None,
                f"a = {action} ({ACTION_NAMES[action]})",
                vmin=vmin,
                vmax=vmax,
            )
        fig.colorbar(image, ax=axes, label="Q(s, a)  (expected discounted return)", shrink=0.6)
        fig.suptitle(title)
        return fig

    def plot_convergence(
        self,
        vi_history: list[float],
        qi_history: list[float],
        gamma: float = 0.95,
        epsilon: float | None = 1e-4,
    ) -> Figure:
        """Sup-norm change per sweep of both algorithms (log scale) with the contraction
        bound ``||x_{k+1} - x_k|| <= gamma^k ||x_1 - x_0||``."""
        fig = Figure(figsize=(7, 4.5))
        ax = fig.subplots()
        for name, history, style in (
            ("value iteration", vi_history, "o-"),
            ("Q-iteration", qi_history, "s--"),
        ):
            sweeps = np.arange(1, len(history) + 1)
            ax.semilogy(
                sweeps, history, style, markersize=3, label=f"{name} ({len(history)} sweeps)"
            )
        longest = max(len(vi_history), len(qi_history))
        sweeps = np.arange(1, longest + 1)
        first = max(vi_history[0], qi_history[0])
        ax.semilogy(
            sweeps,
            first * gamma ** (sweeps - 1),
            ":",
            color="grey",
            label=f"contraction bound γ^(k−1)·Δ₁ (γ = {gamma})",
        )
        if epsilon is not None:
            ax.axhline(
                epsilon, color="black", linewidth=0.8, label=f"stopping threshold ε = {epsilon:g}"
            )
        ax.set_xlabel("sweep k")
        ax.set_ylabel("sup-norm change  max |x_k − x_(k−1)|")
        ax.set_title("Convergence of value iteration and Q-iteration")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        return fig

    def create_comparison_figure(
        self,
        vi_values: np.ndarray,
        qi_values: np.ndarray,
        vi_policy: np.ndarray,
        qi_policy: np.ndarray,
    ) -> Figure:
        """Side by side: VI values and policy, QI values and policy, their absolute difference."""
        fig = Figure(figsize=(17, 5.2), layout="constrained")
        axes = fig.subplots(1, 3)
        vmin = min(np.min(vi_values), np.min(qi_values))
        vmax = max(np.max(vi_values), np.max(qi_values))
        self.draw_grid(axes[0], vi_values, vi_policy, "Value iteration", vmin=vmin, vmax=vmax)
        image = self.draw_grid(axes[1], qi_values, qi_policy, "Q-iteration", vmin=vmin, vmax=vmax)
        fig.colorbar(image, ax=axes[:2], label="V(s)", shrink=0.8)
        difference = np.abs(np.asarray(vi_values) - np.asarray(qi_values))
        ax = axes[2]
        grid = np.ma.masked_array(difference.reshape(self.grid_size, -1), mask=self.absorbing_cells)
        diff_image = ax.imshow(grid, cmap="magma")
        ax.set_title(f"|V_VI − V_QI| (max {difference.max():.1e})")
        ax.set_xlabel("column")
        ax.set_ylabel("row")
        fig.colorbar(diff_image, ax=ax, label="absolute difference", shrink=0.8)
        return fig


def visualize_results(results_dir: str | Path = RESULTS_DIR) -> dict[str, Path]:
    """Redraw every figure from the files ``train.py`` saved; returns the written paths."""
    results_dir = Path(results_dir)
    try:
        vi = np.load(results_dir / "value_function.npz")
        qi = np.load(results_dir / "q_function.npz")
        policies = np.load(results_dir / "optimal_policy.npz")
    except FileNotFoundError as error:
        raise FileNotFoundError(
            f"{error.filename} is missing: run `python train.py` first"
        ) from None
    gamma, epsilon = float(vi["gamma"]), float(vi["epsilon"])
    visualizer = GridWorldVisualizer()
    qi_values = qi["q_values"].max(axis=1)
    figures = {
        "value_heatmap.png": visualizer.plot_value_function(
            vi["values"], "Optimal values V* with the optimal policy", policies["policy"]
        ),
        "policy_arrows.png": visualizer.plot_policy(policies["policy"]),
        "q_functions.png": visualizer.plot_q_function(qi["q_values"]),
        "convergence.png": visualizer.plot_convergence(
            list(vi["history"]), list(qi["history"]), gamma, epsilon
        ),
        "comparison.png": visualizer.create_comparison_figure(
            vi["values"], qi_values, policies["vi_policy"], policies["qi_policy"]
        ),
    }
    out = results_dir / "visualizations"
    out.mkdir(parents=True, exist_ok=True)
    return {name: atomic_save_figure(out / name, figure) for name, figure in figures.items()}


if __name__ == "__main__":
    for path in visualize_results().values():
        print(f"wrote {path}")
