"""The Problem 2 part of the report, assembled from its section modules."""

from __future__ import annotations

from typing import Any

from report_inputs import Results
from report_layout import Block, Heading
from report_problem2_analysis import failures, limits, map_panel, message_use, strategies
from report_problem2_data import P2, SECTIONS
from report_problem2_training import (
    architecture,
    environment,
    final_success,
    hyperparameters,
    reward_choice,
    training_curves,
)

__all__ = ["SECTIONS", "headline", "problem2_blocks"]


def problem2_blocks(results: Results) -> list[Block]:
    """Every block of the Problem 2 part."""
    p2 = P2.load(results)
    blocks: list[Block] = [Heading(SECTIONS[0], level=1)]
    sections = (environment, reward_choice, architecture, hyperparameters, training_curves,
                final_success, message_use, strategies, failures, map_panel, limits)  # fmt: skip
    for section in sections:
        blocks += section(p2)
    return blocks


def headline(results: Results) -> dict[str, Any]:
    """Headline numbers for the title page (None where missing)."""
    p2 = P2.load(results)
    table, _ = p2.success("main")
    return {mode: table[mode]["eps"].mean for mode in table}
