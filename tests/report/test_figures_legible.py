"""Every figure the report places is legible when printed: each one is redrawn from the
committed results by the code that writes it, and its smallest text, scaled to the width
at which the report places the image, is at least 8 pt; one legend at most per figure."""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
from pathlib import Path

import matplotlib
import numpy as np
import pytest
import typst
from matplotlib.figure import Figure
from matplotlib.text import Text

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("report_build", ROOT / "report" / "build.py")
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)

MIN_PRINTED_POINTS = 8.0
A4_WIDTH, MARGIN = 595.28, 2.2 / 2.54 * 72  # points; report.typ: a4, margin x 2.2 cm
TEXT_WIDTH = A4_WIDTH - 2 * MARGIN
P1_RESULTS = ROOT / "problem1" / "results"
P2_RESULTS = ROOT / "problem2" / "results"
EVALUATION = P2_RESULTS / "evaluation_results"


def placed_widths() -> dict[str, float]:
    """Image file name -> the width (points) at which report.pdf or its companion places it."""
    widths = {}
    for main in build.DOCUMENTS.values():
        figures = json.loads(typst.query(str(ROOT / main), "figure", **build.typst_options()))
        for figure in figures:
            body = figure.get("body", {})
            if body.get("func") != "image":
                continue
            # e.g. "0% + 259.2pt" or "100% + 0pt"
            percent, points = (float(part.rstrip("%pt")) for part in body["width"].split(" + "))
            widths[Path(body["source"]).name] = percent / 100 * TEXT_WIDTH + points
    return widths


def read_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def draw_problem1(out: Path) -> None:
    import stochasticity_study
    from visualize import visualize_results

    for name in ("value_function.npz", "q_function.npz", "optimal_policy.npz"):
        shutil.copy(P1_RESULTS / name, out / name)
    visualize_results(out)
    settings = read_json(P1_RESULTS / "stochasticity_study.json")["settings"]
    stochasticity_study.plot_policies(settings).savefig(
        out / "stochasticity_policies.png", bbox_inches="tight"
    )


def draw_training_curves(out: Path) -> None:
    from train import plot_training_curves

    manifest = read_json(P2_RESULTS / "agent_models" / "manifest.json")
    (out / "agent_models").mkdir()
    shutil.copy(P2_RESULTS / "agent_models" / "hyperparameters.json", out / "agent_models")
    shutil.copytree(P2_RESULTS / "training_logs", out / "training_logs")
    plot_training_curves(
        out / "training_logs", manifest["modes"], manifest["seeds"], manifest["hyperparameters"]
    )


def draw_evaluation(out: Path) -> None:
    from analysis.estimate_plots import (
        plot_failure_decomposition,
        plot_interventions,
        plot_measures,
    )
    from analysis.plots import EpisodeTrace, plot_trajectories

    measures = read_json(EVALUATION / "communication_measures.json")["experiments"]["main"]
    aggregates = {mode: entry["aggregate"] for mode, entry in measures.items()}
    plot_measures(aggregates, "K2", out / "communication_measures.png")
    interventions = read_json(EVALUATION / "interventions.json")["experiments"]["main"]
    plot_interventions(interventions, out / "interventions.png")
    performance = read_json(EVALUATION / "performance.json")["experiments"]["main"]
    plot_failure_decomposition(performance["modes"], out / "failure_decomposition.png")
    shown = read_json(EVALUATION / "trajectories.json")  # the episodes the figure draws
    grid = np.array(performance["grid"])
    rows, messages = [], []
    for mode, entry in shown["modes"].items():
        traces = [
            EpisodeTrace(
                positions=np.stack([episode["cells"][a] for a in "AB"], axis=1),
                messages=np.zeros((episode["length"], 2)),
                success=episode["success"],
                description=episode["description"],
            )
            for episode in entry["episodes"]
        ]
        rows.append((mode, (traces + [None])[:2]))
        messages.append(np.random.default_rng(0).uniform(0.99, 1.0, (2, *grid.shape)))
    plot_trajectories(rows, grid, out / "trajectories.png", messages)


def draw_studies(out: Path) -> None:
    from studies import map_pool_study
    from studies.memory import study as memory_study
    from studies.multiplicity import panel_effects
    from studies.one_step import beacon_study, unseen, why
    from studies.one_step.panel_outputs import plot_panel
    from studies.panel_outputs import plot_effects
    from studies.reward_study_outputs import plot_study

    studies = P2_RESULTS / "studies"
    plot_study(read_json(studies / "reward" / "reward_study.json"), out / "reward_study.png")
    pool = read_json(studies / "map_pool" / "map_pool.json")
    map_pool_study.plot(out / "map_pool.png", pool)
    memory_study.plot(out / "memory.png", read_json(studies / "memory" / "memory.json"), pool)
    panel = studies / "panel" / "panel.json"
    if panel.is_file():  # the report places the panel's figure only when the panel has run
        effects = read_json(panel)
        plot_effects(out / "panel_effects.png", effects, panel_effects(effects)["maps"])
    memory_panel = studies / "memory_panel"
    if (memory_panel / "memory_panel.json").is_file():
        plot_panel(out / "memory_panel.png", read_json(memory_panel / "memory_panel.json"))
    if (memory_panel / "why" / "why.json").is_file():
        shown = read_json(memory_panel / "why" / "why.json")["shown_episodes"]
        why.plot_episodes(out / "why.png", shown)
    if (studies / "one_step_unseen" / "unseen.json").is_file():
        unseen.plot(out / "unseen.png", read_json(studies / "one_step_unseen" / "unseen.json"))
    if (studies / "beacon" / "beacon.json").is_file():
        beacon_study.plot(out / "beacon.png", read_json(studies / "beacon" / "beacon.json"))


def printed_sizes(figure: Figure, tight: bool, placed: float) -> tuple[float, int]:
    """(the smallest text of ``figure`` in points as printed ``placed`` points wide, the
    number of legends)."""
    padding = 2 * matplotlib.rcParams["savefig.pad_inches"]  # around a tight box
    width = figure.get_tightbbox().width + padding if tight else figure.get_figwidth()  # inches
    sizes = [
        text.get_fontsize()
        for text in figure.findobj(Text)
        if text.get_visible() and text.get_text().strip() and text.get_figure() is not None
    ]
    legends = len(figure.legends) + sum(ax.get_legend() is not None for ax in figure.axes)
    return min(sizes) * placed / (width * 72), legends


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Figure, bool]]:
    """Every figure the producers save: file name -> (figure, saved with a tight box)."""
    saved: dict[str, tuple[Figure, bool]] = {}
    original = Figure.savefig

    def record(self: Figure, fname, *args, **kwargs) -> None:
        original(self, fname, *args, **kwargs)
        name = re.sub(r"\.tmp\.?\d+", "", Path(str(fname)).name).lstrip(".")  # of temporaries
        saved[Path(name).stem + ".png"] = (self, kwargs.get("bbox_inches") == "tight")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Figure, "savefig", record)
        for draw in (draw_problem1, draw_training_curves, draw_evaluation, draw_studies):
            draw(tmp_path_factory.mktemp(draw.__name__))
    return saved


def test_every_placed_figure_prints_its_text_at_8_points_or_more(drawn: dict) -> None:
    widths = placed_widths()
    assert set(widths) <= set(drawn), f"figures not redrawn here: {set(widths) - set(drawn)}"
    too_small = {}
    for name, placed in widths.items():
        smallest, _ = printed_sizes(*drawn[name], placed)
        if smallest < MIN_PRINTED_POINTS:
            too_small[name] = round(smallest, 2)
    assert too_small == {}


def test_every_placed_figure_has_one_legend_at_most(drawn: dict) -> None:
    counts = {name: printed_sizes(*drawn[name], 1.0)[1] for name in placed_widths()}
    assert {name: n for name, n in counts.items() if n > 1} == {}
