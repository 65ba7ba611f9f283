"""Problem 2 inputs for the report, loaded once, and what the section modules share.

Success rates come from ``evaluation_results/performance.json`` (``python evaluate.py``:
1000 fixed test episodes per trained seed, mean over seeds with a 95 % bootstrap CI) when
it exists; before that, from the trainer's own final test (``*_final.json``, same episode
protocol) with the range over seeds instead of a CI, and the text says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from report_inputs import Results, missing_note
from report_layout import Block, Figure, Note
from report_rules import (
    pct,
    pct_ci,
)

TRAIN_COMMAND = "make problem2"
EVAL_COMMAND = "cd problem2 && python evaluate.py"
CONDITIONS = ("greedy", "eps")
# Success targets set by the learning issue (ε = 0.05 unless marked greedy); not results.
TARGETS = (("full", "eps", 0.85), ("full", "greedy", 0.75), ("comm", "eps", 0.55),
           ("independent", "eps", 0.40))  # fmt: skip
FEATURES = ("on_target", "sees_target", "target_distance", "agent_distance", "time_step")
FAILURE_KINDS = ("swapping", "parked", "looping", "other")
SECTIONS = (
    "Problem 2: Two communicating DQN agents",
    "2.1 Environment",
    "2.2 Reward choice",
    "2.3 Architecture and DIAL message training",
    "2.4 Hyperparameters",
    "2.5 Training curves",
    "2.6 Final success rates",
    "2.7 Is the message used?",
    "2.8 Learned strategies",
    "2.9 Failure analysis",
    "2.10 Map panel and generalisation",
    "2.11 Limits and honest negatives",
)


@dataclass
class Stat:
    """A success rate (or other quantity) over training seeds."""

    mean: float | None
    ci: list[float] | None = None  # 95 % bootstrap CI over seeds (None: not computed)
    per_seed: list[float] = field(default_factory=list)

    @classmethod
    def of(cls, entry: dict | None) -> Stat:
        """From an ``analysis_stats.seed_statistics`` dict."""
        if not entry:
            return cls(None)
        return cls(entry.get("mean"), entry.get("ci95"), list(entry.get("per_seed") or []))

    @classmethod
    def values(cls, values: list[float]) -> Stat:
        return cls(float(np.mean(values)) if values else None, None, list(values))

    def text(self) -> str:
        """``73.4 % [68.0, 78.1]``, or with the seed range ``73.4 % (range 60.0–80.0)``."""
        if self.ci or len(self.per_seed) < 2:
            return pct_ci(self.mean, self.ci)
        present = [v for v in self.per_seed if v is not None]
        return f"{pct(self.mean)} (range {100 * min(present):.1f}–{100 * max(present):.1f})"


@dataclass
class P2:
    """Every Problem 2 input, loaded once (None / empty where missing)."""

    results: Results
    hyper: dict | None
    grid: np.ndarray | None
    baselines: dict | None
    performance: dict | None
    communication: dict | None
    generalization: dict | None
    notes: list[str] = field(default_factory=list)

    @classmethod
    def load(cls, results: Results) -> P2:
        grid_json = results.json(results.p2("agent_models/map.json"))
        evaluation = results.p2("evaluation_results")
        return cls(
            results,
            results.json(results.p2("agent_models/hyperparameters.json")),
            np.array(grid_json["grid"]) if grid_json and "grid" in grid_json else None,
            results.json(evaluation / "baselines.json"),
            results.json(evaluation / "performance.json"),
            results.json(evaluation / "communication_analysis.json"),
            results.json(evaluation / "generalization.json"),
        )

    def root(self, experiment: str) -> Path:
        return (
            self.results.problem2
            if experiment == "main"
            else self.results.p2(f"studies/{experiment}")
        )

    def experiment(self, name: str) -> dict | None:
        if not self.performance:
            return None
        return self.performance.get("experiments", {}).get(name)

    def success(self, name: str = "main") -> tuple[dict[str, dict[str, Stat]], bool]:
        """mode -> condition -> success Stat of experiment ``name``, and whether the numbers
        come from ``performance.json`` (True) or the trainer's final tests (False)."""
        experiment = self.experiment(name)
        if experiment and experiment.get("modes"):
            table = {
                mode: {c: Stat.of(entry[c]["success_rate"]) for c in CONDITIONS}
                for mode, entry in experiment["modes"].items()
            }
            return table, True
        finals = self.results.final_runs(self.root(name))
        table = {
            mode: {c: Stat.values([r[c]["success_rate"] for r in runs]) for c in CONDITIONS}
            for mode, runs in finals.items()
        }
        return table, False

    def baseline(self, name: str, map_seed: int | None = None) -> dict | None:
        """Random or oracle summary on a map (default: the training map)."""
        key = str(map_seed if map_seed is not None else (self.hyper or {}).get("map_seed", 641))
        experiment = self.experiment("main")
        if map_seed is None and experiment and name in experiment.get("baselines", {}):
            return experiment["baselines"][name]
        if self.baselines:
            return self.baselines.get("maps", {}).get(key, {}).get(name)
        return None


def _source_note(from_evaluation: bool) -> str:
    if from_evaluation:
        return (
            "Numbers: evaluation_results/performance.json (mean over training seeds, 95 % "
            "percentile-bootstrap CI over seeds in brackets)."
        )
    return (
        "Numbers: the trainer's final test of each seed (training_logs/*_final.json, 1000 "
        "episodes); evaluate.py's CIs were not available, so the range over seeds is shown."
    )


def _figure(path: Path, caption: str, what: str, command: str, height: float = 4.6) -> Block:
    found = Results.png(path)
    return Figure(found, caption, height) if found else Note(missing_note(what, command))


# --------------------------------------------------------------------------- sections
