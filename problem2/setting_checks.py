"""Checks of single settings, for :data:`train_config.FIELD_CHECKS` and the study scripts.

A check maps a value to None when it is allowed, or to the problem (``"must be an integer
>= 1"``); :class:`SettingError` carries the setting's name, the problem and the value, and
:meth:`SettingError.usage` words it as the usage error of the flag ``--name``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

Check = Callable[[Any], str | None]


class SettingError(ValueError):
    """An invalid training setting; ``name`` is the field (the flag is ``--name``)."""

    def __init__(self, name: str, problem: str, value: Any) -> None:
        super().__init__(f"{name} {problem}, got {value!r}")
        self.name, self.problem, self.value = name, problem, value

    def usage(self) -> str:
        """The usage error: ``argument --name: problem, got value``."""
        return f"argument --{self.name}: {self.problem}, got {_shown(self.value)}"


def check_value(name: str, value: Any, check: Check) -> None:
    """Raise :class:`SettingError` if ``check`` finds a problem with ``value``."""
    problem = check(value)
    if problem:
        raise SettingError(name, problem, value)


def _shown(value: Any) -> str:
    if isinstance(value, list):
        return " ".join(str(v) for v in value)
    return repr(value) if isinstance(value, str) else str(value)


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def int_in(low: int, high: int | None = None) -> Check:
    allowed = f"an integer >= {low}" if high is None else f"an integer in {low}..{high}"

    def check(value: Any) -> str | None:
        ok = is_int(value) and value >= low and (high is None or value <= high)
        return None if ok else f"must be {allowed}"

    return check


def number_in(low: float, high: float, low_open: bool = False, high_open: bool = False) -> Check:
    left, right = "(" if low_open else "[", ")" if high_open else "]"
    shown_high = "inf)" if math.isinf(high) else f"{high:g}{right}"
    allowed = f"a finite number in {left}{low:g}, {shown_high}"

    def check(value: Any) -> str | None:
        if not (isinstance(value, (int, float)) and not isinstance(value, bool)):
            return f"must be {allowed}"
        ok = (
            math.isfinite(value)
            and (value > low if low_open else value >= low)
            and (value < high if high_open else value <= high)
        )
        return None if ok else f"must be {allowed}"

    return check


def one_of(*choices: str) -> Check:
    return lambda value: None if value in choices else f"must be one of {', '.join(choices)}"


def boolean(value: Any) -> str | None:
    return None if isinstance(value, bool) else "must be True or False"


def modes_from(modes: tuple[str, ...]) -> Check:
    """``all`` or a comma-separated list of distinct ``modes``."""
    message = f"must be all or a comma-separated list of distinct modes from {', '.join(modes)}"

    def check(value: Any) -> str | None:
        if value == "all":
            return None
        if not isinstance(value, str) or not value:
            return message
        chosen = value.split(",")
        return None if set(chosen) <= set(modes) and len(set(chosen)) == len(chosen) else message

    return check


def distinct_ints_in(low: int, high: int) -> Check:
    def check(value: Any) -> str | None:
        ok = (
            isinstance(value, (list, tuple))
            and all(is_int(s) and low <= s <= high for s in value)
            and len(set(value)) == len(value)
        )
        return None if ok else f"must be distinct integers in {low}..{high}"

    return check


def grid_sides_in(low: int, high: int) -> Check:
    """One side (a square grid) or two, rows and columns."""

    def check(value: Any) -> str | None:
        sides = value if isinstance(value, list) else [value]
        ok = len(sides) in (1, 2) and all(is_int(s) and low <= s <= high for s in sides)
        return None if ok else f"must be one or two integers in {low}..{high}"

    return check


def epsilon_decay(value: Any) -> str | None:
    if value == 0 and not isinstance(value, bool):
        return None
    if number_in(0.0, 1.0, low_open=True, high_open=True)(value) is None:
        return None
    return (
        "must be 0 (linear schedule) or a multiplicative factor per episode in (0, 1), e.g. 0.995"
    )


def folder(value: Any) -> str | None:
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        return "must be a folder path"
    return "must be a folder, not a file" if Path(value).is_file() else None
