"""Reading the result files the report is built from, tolerating missing ones.

:class:`Results` looks files up under the two results roots (``problem1/results`` and
``problem2/results``) and returns ``None`` for a file that is missing or unreadable, so
every section can print a "not available" note instead of failing; :func:`missing_note`
words that note.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
MODES = ("independent", "comm", "full")
RUN_FILE = re.compile(r"^(independent|comm|full)_seed(\d+)_final\.json$")


def missing_note(what: str, command: str = "make") -> str:
    """The sentence printed where an input is missing."""
    return f"Not available: {what} was not found when this report was built (run `{command}`)."


@dataclass
class Results:
    """The results roots of both problems."""

    problem1: Path
    problem2: Path

    @classmethod
    def under(cls, root: Path) -> Results:
        """The roots of a repository checkout (or a fixture shaped like one) at ``root``."""
        root = Path(root)
        return cls(root / "problem1" / "results", root / "problem2" / "results")

    def p1(self, relative: str) -> Path:
        return self.problem1 / relative

    def p2(self, relative: str) -> Path:
        return self.problem2 / relative

    # ------------------------------------------------------------------ readers
    @staticmethod
    def json(path: Path) -> Any | None:
        """Parsed JSON of ``path``, or None if it is missing or not valid JSON."""
        try:
            return json.loads(Path(path).read_text())
        except (OSError, ValueError):
            return None

    @staticmethod
    def csv(path: Path) -> dict[str, np.ndarray] | None:
        """Columns of a numeric CSV as float arrays (empty cells and 'nan' become NaN)."""
        try:
            with Path(path).open(newline="") as handle:
                rows = list(csv.DictReader(handle))
        except OSError:
            return None
        if not rows:
            return None

        def number(text: str) -> float:
            try:
                return float(text)
            except ValueError:
                return math.nan

        return {key: np.array([number(r[key] or "nan") for r in rows]) for key in rows[0]}

    @staticmethod
    def npz(path: Path) -> dict[str, np.ndarray] | None:
        try:
            with np.load(path) as data:
                return {key: data[key] for key in data.files}
        except (OSError, ValueError):
            return None

    @staticmethod
    def png(path: Path) -> Path | None:
        """``path`` if it is a readable PNG file, else None."""
        path = Path(path)
        try:
            with path.open("rb") as handle:
                return path if handle.read(8) == b"\x89PNG\r\n\x1a\n" else None
        except OSError:
            return None

    # ------------------------------------------------------------------ Problem 2 runs
    def final_runs(self, root: Path) -> dict[str, list[dict]]:
        """The trainer's final test of every run under ``root/training_logs`` by mode
        (``<mode>_seed<seed>_final.json``), sorted by seed."""
        runs: dict[str, list[tuple[int, dict]]] = {}
        logs = Path(root) / "training_logs"
        for path in sorted(logs.glob("*_final.json")) if logs.is_dir() else []:
            match = RUN_FILE.match(path.name)
            data = self.json(path)
            if match and isinstance(data, dict) and "greedy" in data and "eps" in data:
                runs.setdefault(match[1], []).append((int(match[2]), data))
        return {m: [d for _, d in sorted(runs[m], key=lambda p: p[0])] for m in MODES if m in runs}

    def training_logs(self, root: Path) -> dict[str, list[dict[str, np.ndarray]]]:
        """The CSV training logs under ``root/training_logs`` by mode, sorted by seed."""
        logs = Path(root) / "training_logs"
        found: dict[str, list[tuple[int, dict]]] = {}
        for path in sorted(logs.glob("*_seed*.csv")) if logs.is_dir() else []:
            match = re.match(r"^(independent|comm|full)_seed(\d+)\.csv$", path.name)
            table = self.csv(path) if match else None
            if table is not None and "env_steps" in table:
                found.setdefault(match[1], []).append((int(match[2]), table))
        return {
            m: [t for _, t in sorted(found[m], key=lambda p: p[0])] for m in MODES if m in found
        }
