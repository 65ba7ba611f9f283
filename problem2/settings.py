"""How a value is checked, once for the whole of Problem 2: :func:`setting` declares a
dataclass field of ``train_config.TrainConfig`` (default, help, allowed range); a check maps a
value to None (allowed) or to the problem, phrased with the allowed range ("must be an integer
>= 1"); :class:`SettingError` carries every problem found, each naming its field (the flag
``--name``). :func:`is_integer`, :func:`positive_int` and :func:`check_seed` are the checks
the environment, the networks and the replay buffer apply to their arguments."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import field
from pathlib import Path
from typing import Any

import numpy as np

Check = Callable[[Any], str | None]
Problem = tuple[str, str, Any]  # (field name, what is wrong, the value)


class SettingError(ValueError):
    """Invalid training settings: ``problems`` lists (name, problem, value) for each, the
    flag being ``--name``; ``name``, ``problem`` and ``value`` are the first one's."""

    def __init__(self, name: str, problem: str, value: Any, *more: Problem) -> None:
        self.problems: list[Problem] = [(name, problem, value), *more]
        super().__init__("\n".join(f"{n} {p}, got {v!r}" for n, p, v in self.problems))
        self.name, self.problem, self.value = name, problem, value


def check_value(name: str, value: Any, check: Check) -> None:
    """Raise :class:`SettingError` if ``check`` finds a problem with ``value``."""
    problem = check(value)
    if problem:
        raise SettingError(name, problem, value)


def is_integer(value: object) -> bool:
    """A Python or NumPy integer, not a bool."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def positive_int(value: object, name: str) -> int:
    """``value`` as an int if it is an integer >= 1; ValueError naming ``name`` otherwise."""
    if not is_integer(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_seed(seed: object, name: str = "seed") -> int | None:
    """``None`` or a non-negative integer (what NumPy's generators accept)."""
    if seed is not None and (not is_integer(seed) or seed < 0):
        raise ValueError(f"{name} must be None or a non-negative integer, got {seed!r}")
    return None if seed is None else int(seed)


def int_in(low: int, high: int | None = None) -> Check:
    allowed = f"an integer >= {low}" if high is None else f"an integer in {low}..{high}"

    def check(value: Any) -> str | None:
        ok = is_integer(value) and value >= low and (high is None or value <= high)
        return None if ok else f"must be {allowed}"

    return check


def number_in(low: float, high: float, low_open: bool = False, high_open: bool = False) -> Check:
    left, right = "(" if low_open else "[", ")" if high_open else "]"
    shown_high = "inf)" if math.isinf(high) else f"{high:g}{right}"
    allowed = f"a finite number in {left}{low:g}, {shown_high}"

    def check(value: Any) -> str | None:
        ok = (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and math.isfinite(value)
            and (value > low if low_open else value >= low)
            and (value < high if high_open else value <= high)
        )
        return None if ok else f"must be {allowed}"

    return check


def one_of(*choices: str) -> Check:
    return lambda value: None if value in choices else f"must be one of {', '.join(choices)}"


def boolean(value: Any) -> str | None:
    return None if isinstance(value, bool) else "must be True or False"


def folder(value: Any) -> str | None:
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        return "must be a folder path"
    return "must be a folder, not a file" if Path(value).is_file() else None


def mode_list(modes: Sequence[str]) -> Check:
    """``all`` or a comma-separated list of distinct ``modes``."""
    shown = ", ".join(modes)

    def check(value: Any) -> str | None:
        if value == "all":
            return None
        chosen = value.split(",") if isinstance(value, str) and value else []
        if chosen and set(chosen) <= set(modes) and len(set(chosen)) == len(chosen):
            return None
        return f"must be all or a comma-separated list of distinct modes from {shown}"

    return check


def distinct_ints(low: int, high: int) -> Check:
    """A list (or tuple) of distinct integers in low..high."""

    def check(value: Any) -> str | None:
        ok = (
            isinstance(value, (list, tuple))
            and all(is_integer(v) and low <= v <= high for v in value)
            and len(set(value)) == len(value)
        )
        return None if ok else f"must be distinct integers in {low}..{high}"

    return check


def one_or_two_ints(low: int, high: int) -> Check:
    """An integer in low..high, or a list of one or two (e.g. a grid's rows and columns)."""

    def check(value: Any) -> str | None:
        values = value if isinstance(value, list) else [value]
        ok = len(values) in (1, 2) and all(is_integer(v) and low <= v <= high for v in values)
        return None if ok else f"must be one or two integers in {low}..{high}"

    return check


def setting(
    default: Any,
    help: str,
    check: Check,
    items: tuple[Callable[[str], Any], str] | None = None,
) -> Any:
    """A dataclass field declared once: its default, one-line ``help`` and
    allowed-range ``check``; ``items`` = (item type, metavar) makes its flag a list flag. A
    list default, or a function (e.g. the core count), is built anew for each config."""
    metadata = {"help": help, "check": check, "items": items}
    if callable(default):
        return field(default_factory=default, metadata=metadata)
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=metadata)
    return field(default=default, metadata=metadata)
