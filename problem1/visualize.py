"""Figures for Problem 1: value heatmap with policy arrows, policy, Q-functions, convergence.

    python visualize.py [--results_dir results]

Redraws the figures in <results_dir>/visualizations/ from the .npz files that train.py
wrote (value_heatmap.png, policy_arrows.png, q_functions.png, convergence.png and .svg,
comparison.png). Refuses arrays that come from different train.py runs.

Figures are drawn at about the size they are printed on A4 (at most 6.5 in wide) with
text of at least 8 pt.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path

from cli import RESULTS_DIR, add_results_dir_argument, new_parser

import numpy as np
from environment import ACTION_NAMES, MOVES, GridWorldEnv
from file_io import atomic_save_figure, make_console_safe, remove_stale_temporaries, shown
from matplotlib.axes import Axes
from matplotlib.figure import Figure  # figures without pyplot: no GUI backend, no global state
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

CELL_STYLE = {  # frame colour, legend entry
    "goal": ("#1a9641", "goal: +10, episode ends (no value)"),
    "penalty": ("#d7191c", "penalty cell: −5"),
    "start": ("#2b83ba", "start"),
}
GOAL_FILL = {"facecolor": "0.88", "edgecolor": "0.55", "hatch": "//"}  # drawn and in the legend
DETOUR_LABEL = "detour: a worse move without drift"
# a white diamond edged in black, readable on every colour of the scale
DETOUR_MARK = {
    "marker": "D",
    "markersize": 6,
    "markerfacecolor": "white",
    "markeredgecolor": "black",
}
VALUE_FONT = 9
SMALL_FONT = 8  # the smallest text in any figure, in points at the width the report prints it


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
        self.absorbing_cells = self.env.obstacle_mask.copy()
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
        compact: bool = False,
        detours: Iterable[int] = (),
        value_font: float = VALUE_FONT,
    ):
        """Draw one grid on ``ax``: optional value heatmap (S,), optional arrows (S,).

        Obstacles are black; the goal, penalty and start cells are framed in colour (explained
        by :meth:`add_cell_legend`), the ``detours`` states by a white diamond in the lower
        right corner.
        Arrows and values are black on light cells and white on dark ones. ``compact``: a
        small panel of a multi-panel figure (thinner lines, one decimal, smaller labels).
        ``value_font``: the size of the values written in the cells, in points. Returns the
        heatmap image (for a colour bar), or None.
        """
        n = self.grid_size
        image = None
        if values is not None:
            grid = np.ma.masked_array(
                np.asarray(values, dtype=float).reshape(n, n), mask=self.absorbing_cells
            )
            image = ax.imshow(grid, cmap="viridis", vmin=vmin, vmax=vmax)
            if annotate:  # above the arrow, if there is one
                self._annotate_values(
                    ax, grid, image, compact, -0.18 if policy is not None else 0, value_font
                )
        else:
            ax.imshow(np.zeros((n, n)), cmap="Greys", vmin=0, vmax=1)
        for r, c in self.env.obstacles:
            ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, color="black"))
        goal_r, goal_c = self.env.goal_pos
        # the goal holds no value (V = 0, the episode ends there): grey and hatched, off the scale
        ax.add_patch(
            Rectangle(
                (goal_c - 0.5, goal_r - 0.5),
                1,
                1,
                linewidth=0,
                **GOAL_FILL,
            )
        )
        special = [
            ("goal", [self.env.goal_pos]),
            ("penalty", self.env.penalties),
            ("start", [self.env.start_pos]),
        ]
        for kind, cells in special:
            for r, c in cells:
                ax.add_patch(self._frame(r, c, 0.42, CELL_STYLE[kind][0], 2 if compact else 3))
        for state in detours:  # in the lower right corner, clear of the value and the arrow
            r, c = divmod(int(state), n)
            ax.plot(c + 0.34, r + 0.34, clip_on=False, **DETOUR_MARK)
        if policy is not None:
            shift = 0.0 if values is None or not annotate else 0.2
            self._draw_arrows(ax, np.asarray(policy), image, shift, compact)
        ax.set_xticks(range(n))
        ax.set_yticks(range(n))
        font = SMALL_FONT if compact else VALUE_FONT
        ax.tick_params(labelsize=font)
        ax.set_xlabel("column", fontsize=font)
        ax.set_ylabel("row", fontsize=font)
        ax.set_title(title, fontsize=VALUE_FONT if compact else 10)
        return image

    @staticmethod
    def _frame(row: int, col: int, half: float, colour: str, width: float, **style) -> Rectangle:
        """An unfilled square of half-side ``half`` around a cell's centre."""
        corner = (col - half, row - half)
        return Rectangle(
            corner, 2 * half, 2 * half, fill=False, edgecolor=colour, lw=width, **style
        )

    def add_cell_legend(self, fig: Figure, detours: bool = False) -> None:
        """Legend of the cells drawn as :meth:`draw_grid` draws them (the goal's grey hatching
        inside its frame, the other coloured frames, obstacles, the detour mark), below the
        figure."""
        handles, labels = [], []
        for kind, (colour, label) in CELL_STYLE.items():
            frame = Patch(facecolor="none", edgecolor=colour, linewidth=2)
            # the goal: its hatched fill with the frame drawn over it (a tuple overlays both)
            handles.append((Patch(linewidth=0, **GOAL_FILL), frame) if kind == "goal" else frame)
            labels.append(label)
        handles.append(Patch(facecolor="black"))
        labels.append("obstacle")
        if detours:
            handles.append(Line2D([], [], linestyle="none", **DETOUR_MARK))
            labels.append(DETOUR_LABEL)
        fig.legend(
            handles,
            labels,
            loc="outside lower center",
            ncols=3 if detours else 2,
            fontsize=SMALL_FONT,
            frameon=False,
        )

    @staticmethod
    def _contrast_colour(image, value: float) -> str:
        """Black or white, whichever contrasts more with the heatmap colour under it (WCAG
        contrast ratio of relative luminances): black on yellow and green, white on blue and
        purple."""
        if image is None or np.isnan(value):
            return "black"
        rgb = np.asarray(image.cmap(image.norm(value))[:3])
        linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
        luminance = float(linear @ np.array([0.2126, 0.7152, 0.0722]))
        return "black" if (luminance + 0.05) / 0.05 >= 1.05 / (luminance + 0.05) else "white"

    def _annotate_values(
        self,
        ax: Axes,
        grid: np.ma.MaskedArray,
        image,
        compact: bool,
        shift: float,
        value_font: float = VALUE_FONT,
    ) -> None:
        for (r, c), value in np.ndenumerate(grid.filled(np.nan)):
            if np.isnan(value):
                continue
            ax.text(
                c,
                r + shift,
                self._compact_label(value) if compact else f"{value:.2f}",
                ha="center",
                va="center",
                fontsize=value_font,
                color=self._contrast_colour(image, value),
            )

    @staticmethod
    def _compact_label(value: float) -> str:
        """One decimal, or none from 9.95 up, so that no label is wider than a cell."""
        return f"{value:.0f}" if abs(value) >= 9.95 else f"{value:.1f}"

    def _draw_arrows(
        self, ax: Axes, policy: np.ndarray, image, shift: float, compact: bool
    ) -> None:
        """One arrow per decision state (not the goal, not obstacles), in the cell's contrast
        colour."""
        length = 0.36 if shift else 0.6
        values = image.get_array().filled(np.nan) if image is not None else None
        for state, action in enumerate(policy.reshape(-1)):
            r, c = divmod(state, self.grid_size)
            if self.absorbing_cells[r, c]:
                continue
            dr, dc = MOVES[int(action)]
            colour = self._contrast_colour(image, np.nan if values is None else values[r, c])
            ax.annotate(
                "",
                xy=(c + length / 2 * dc, r + shift + length / 2 * dr),
                xytext=(c - length / 2 * dc, r + shift - length / 2 * dr),
                arrowprops={
                    "arrowstyle": "-|>",
                    "color": colour,
                    "lw": 1.8 if compact else 2.2,
                    "mutation_scale": 11 if compact else 14,
                    "shrinkA": 0,
                    "shrinkB": 0,
                },
            )

    # ------------------------------------------------------------------ figures
    def plot_value_function(
        self,
        values: np.ndarray,
        title: str = "Optimal state values V*",
        policy: np.ndarray | None = None,
    ) -> Figure:
        """Heatmap of ``values`` (S,) with the value in each cell and optional policy arrows."""
        fig = Figure(figsize=(4.3, 4.6), layout="constrained")
        ax = fig.subplots()
        image = self.draw_grid(ax, values, policy, title)
        colour_bar = fig.colorbar(image, ax=ax, shrink=0.9)
        colour_bar.set_label("V(s)  (expected discounted return)", fontsize=VALUE_FONT)
        colour_bar.ax.tick_params(labelsize=VALUE_FONT)
        self.add_cell_legend(fig)
        return fig

    def plot_policy(self, policy: np.ndarray, title: str = "Optimal policy") -> Figure:
        """Arrows of a deterministic policy (S,) on the map."""
        fig = Figure(figsize=(3.8, 4.2), layout="constrained")
        ax = fig.subplots()
        self.draw_grid(ax, None, policy, title)
        self.add_cell_legend(fig)
        return fig

    def plot_q_function(
        self, q_values: np.ndarray, title: str = "Optimal action values Q*(s, a)"
    ) -> Figure:
        """Four heatmaps, one per action, of ``q_values`` (S, 4) on a shared colour scale."""
        q_values = np.asarray(q_values, dtype=float)
        decision = ~self.absorbing_cells.reshape(-1)
        vmin, vmax = q_values[decision].min(), q_values[decision].max()
        fig = Figure(figsize=(6.3, 6.2), layout="constrained")
        axes = fig.subplots(2, 2)
        for action, ax in enumerate(axes.flat):
            image = self.draw_grid(
                ax,
                q_values[:, action],
                None,
                f"a = {action} ({ACTION_NAMES[action]})",
                vmin=vmin,
                vmax=vmax,
                compact=True,
            )
        colour_bar = fig.colorbar(image, ax=axes, shrink=0.6)
        colour_bar.set_label("Q(s, a)  (expected discounted return)", fontsize=9)
        colour_bar.ax.tick_params(labelsize=SMALL_FONT)
        fig.suptitle(title, fontsize=12)
        self.add_cell_legend(fig)
        return fig

    def plot_convergence(
        self,
        vi_history: list[float],
        qi_history: list[float],
        gamma: float = 0.95,
        epsilon: float | None = 1e-4,
    ) -> Figure:
        """Two panels. Left: the sup-norm change per sweep (log scale) of value iteration and
        of Q-iteration (whose change runs over every (s, a)), with the contraction bound
        ``||x_k - x_(k-1)|| <= gamma^(k-1) ||x_1 - x_0||`` and the stopping threshold. Right:
        Q-iteration's change divided by value iteration's, sweep by sweep (the two curves lie
        close together on the left)."""
        fig = Figure(figsize=(6.3, 2.5), layout="constrained")
        left, right = fig.subplots(1, 2)
        vi = np.asarray(vi_history, dtype=float)
        qi = np.asarray(qi_history, dtype=float)
        sweeps = np.arange(1, len(vi) + 1)
        left.semilogy(sweeps, vi, "o-", ms=3, lw=1.0, color="#1f77b4", label="value iteration")
        left.semilogy(
            np.arange(1, len(qi) + 1),
            qi,
            "s--",
            ms=2.5,
            lw=0.9,
            color="#ff7f0e",
            label="Q-iteration",
        )
        bound_sweeps = np.arange(1, max(len(vi), len(qi)) + 1)
        left.semilogy(
            bound_sweeps,
            max(vi[0], qi[0]) * gamma ** (bound_sweeps - 1),
            ":",
            color="grey",
            label=rf"bound $\gamma^{{k-1}}\Delta_1$ ($\gamma$ = {gamma})",
        )
        if epsilon is not None:
            left.axhline(epsilon, color="black", lw=0.8, label=rf"$\varepsilon$ = {epsilon:g}")
        left.set_ylabel("sup-norm change per sweep", fontsize=SMALL_FONT)
        left.set_title(f"VI ({len(vi)} sweeps) and QI ({len(qi)} sweeps)", fontsize=VALUE_FONT)
        shared = min(len(vi), len(qi))
        ratio = qi[:shared] / np.where(vi[:shared] > 0, vi[:shared], np.nan)
        right.plot(np.arange(1, shared + 1), ratio, "s-", ms=3, lw=1.0, color="#ff7f0e")
        right.axhline(1.0, color="grey", lw=0.8, ls=":")
        right.set_ylabel("QI's change / VI's change", fontsize=SMALL_FONT)
        right.set_title(f"Q-iteration ({len(qi)} sweeps) against VI", fontsize=VALUE_FONT)
        for ax in (left, right):
            ax.set_xlabel(r"sweep $k$", fontsize=SMALL_FONT)
            ax.tick_params(labelsize=SMALL_FONT)
            ax.grid(True, which="major", alpha=0.3)
        fig.legend(loc="outside lower center", ncols=4, fontsize=SMALL_FONT, frameon=False)
        return fig

    def create_comparison_figure(
        self,
        vi_values: np.ndarray,
        qi_values: np.ndarray,
        vi_policy: np.ndarray,
        qi_policy: np.ndarray,
    ) -> Figure:
        """Side by side: VI values (colour) and policy, the same for QI, their absolute
        difference. The panels are small, so the values are not written in the cells."""
        fig = Figure(figsize=(6.5, 2.9), layout="constrained")
        axes = fig.subplots(1, 3)
        decision = ~self.absorbing_cells.reshape(-1)
        both = np.concatenate([np.asarray(vi_values)[decision], np.asarray(qi_values)[decision]])
        vmin, vmax = float(both.min()), float(both.max())
        for ax, values, policy, title in (
            (axes[0], vi_values, vi_policy, "Value iteration"),
            (axes[1], qi_values, qi_policy, "Q-iteration"),
        ):
            image = self.draw_grid(
                ax, values, policy, title, annotate=False, vmin=vmin, vmax=vmax, compact=True
            )
        colour_bar = fig.colorbar(image, ax=axes[:2], shrink=0.8)
        colour_bar.set_label("V(s)", fontsize=SMALL_FONT)
        colour_bar.ax.tick_params(labelsize=SMALL_FONT)
        difference = np.abs(np.asarray(vi_values) - np.asarray(qi_values))
        ax = axes[2]
        grid = np.ma.masked_array(difference.reshape(self.grid_size, -1), mask=self.absorbing_cells)
        # the scale starts at 0; a floor keeps it readable when both solvers agree exactly
        diff_image = ax.imshow(grid, cmap="magma", vmin=0.0, vmax=max(difference.max(), 1e-6))
        ax.set_title(f"|V_VI − V_QI|\n(max {difference.max():.1e})", fontsize=9)
        ax.set_xlabel("column", fontsize=SMALL_FONT)
        ax.set_ylabel("row", fontsize=SMALL_FONT)
        ax.tick_params(labelsize=SMALL_FONT)
        diff_bar = fig.colorbar(diff_image, ax=ax, shrink=0.8)
        diff_bar.set_label("absolute difference", fontsize=SMALL_FONT)
        diff_bar.ax.tick_params(labelsize=SMALL_FONT)
        self.add_cell_legend(fig)
        return fig


def load_run(results_dir: str | Path) -> dict[str, dict[str, np.ndarray]]:
    """The three arrays files of one ``train.py`` run, refused unless they carry the same
    run id (so figures never mix, e.g., a gamma = 0.5 V with a gamma = 0.95 Q)."""
    results_dir = Path(results_dir)
    files = {}
    for name in ("value_function.npz", "q_function.npz", "optimal_policy.npz"):
        try:
            with np.load(results_dir / name) as archive:
                files[name] = {key: archive[key] for key in archive.files}
        except FileNotFoundError:
            raise FileNotFoundError(
                f"{name} is missing in {results_dir}: run `python train.py` first"
            ) from None
    run_ids = {name: str(arrays.get("run_id", "none")) for name, arrays in files.items()}
    if len(set(run_ids.values())) != 1 or "none" in run_ids.values():
        found = ", ".join(f"{name} (run {run_id})" for name, run_id in run_ids.items())
        raise ValueError(
            f"the arrays in {results_dir} do not come from one train.py run: {found}; "
            "run `python train.py` again to rewrite them together"
        )
    return files


def visualize_results(results_dir: str | Path = RESULTS_DIR) -> dict[str, Path]:
    """Redraw every figure from the files ``train.py`` saved; returns the written paths."""
    results_dir = Path(results_dir)
    run = load_run(results_dir)
    vi, qi, policies = run["value_function.npz"], run["q_function.npz"], run["optimal_policy.npz"]
    gamma, epsilon = float(vi["gamma"]), float(vi["epsilon"])
    visualizer = GridWorldVisualizer()
    qi_values = qi["q_values"].max(axis=1)
    convergence = visualizer.plot_convergence(
        list(vi["history"]), list(qi["history"]), gamma, epsilon
    )
    figures = {
        "value_heatmap.png": visualizer.plot_value_function(
            vi["values"], "Optimal values V* with the optimal policy", policies["policy"]
        ),
        "policy_arrows.png": visualizer.plot_policy(policies["policy"]),
        "q_functions.png": visualizer.plot_q_function(qi["q_values"]),
        "convergence.png": convergence,
        "convergence.svg": convergence,
        "comparison.png": visualizer.create_comparison_figure(
            vi["values"], qi_values, policies["vi_policy"], policies["qi_policy"]
        ),
    }
    out = results_dir / "visualizations"
    out.mkdir(parents=True, exist_ok=True)
    return {name: atomic_save_figure(out / name, figure) for name, figure in figures.items()}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    return add_results_dir_argument(new_parser(__doc__)).parse_args(argv)


def main(argv: list[str] | None = None) -> dict[str, Path]:
    make_console_safe()
    args = parse_args(argv)
    remove_stale_temporaries(args.results_dir)
    try:
        load_run(args.results_dir)
    except (FileNotFoundError, ValueError) as error:  # no traceback for a missing or mixed run
        raise SystemExit(f"visualize.py: error: {error}") from None
    written = visualize_results(args.results_dir)
    for path in written.values():
        print(f"wrote {shown(path)}")
    return written


if __name__ == "__main__":
    main()
