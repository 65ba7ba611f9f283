"""Rules for the Problem 1 source: no module reaches into another's private names, and
every text file is opened as UTF-8."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import PROBLEM1

SOURCES = sorted(PROBLEM1.glob("*.py"))


def parsed(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def private_uses(tree: ast.Module) -> list[str]:
    """``x._name`` where ``x`` is not ``self`` or ``cls``."""
    return [
        f"line {node.lineno}: {ast.unparse(node)}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr.startswith("_")
        and not node.attr.startswith("__")
        and not (isinstance(node.value, ast.Name) and node.value.id in {"self", "cls"})
    ]


def text_io_without_encoding(tree: ast.Module) -> list[str]:
    """Builtin ``open`` in text mode, ``.read_text()`` or ``.write_text()`` without
    ``encoding=``."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call) or "encoding" in {k.arg for k in node.keywords}:
            continue
        func = node.func
        if isinstance(func, ast.Name) and func.id == "open":
            modes = [a.value for a in node.args[1:2] if isinstance(a, ast.Constant)]
            modes += [k.value.value for k in node.keywords if k.arg == "mode"]
            if not any("b" in str(mode) for mode in modes):
                found.append(f"line {node.lineno}: {ast.unparse(node)}")
        elif isinstance(func, ast.Attribute) and func.attr in {"read_text", "write_text"}:
            found.append(f"line {node.lineno}: {ast.unparse(node)}")
    return found


def test_there_are_sources() -> None:
    assert {"environment.py", "value_iteration.py", "q_iteration.py"} <= {p.name for p in SOURCES}


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: p.name)
def test_no_private_name_of_another_object_is_used(path: Path) -> None:
    assert private_uses(parsed(path)) == []


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: p.name)
def test_text_files_are_opened_as_utf8(path: Path) -> None:
    assert text_io_without_encoding(parsed(path)) == []


def test_the_rules_catch_offenders() -> None:
    """The checks above find what they look for (so an empty result means something)."""
    tree = ast.parse(
        "env._pos_to_state(0)\nself._x\nopen('x')\nopen('y', 'rb')\n"
        "Path('z').read_text()\nPath('z').write_text('t', encoding='utf-8')\n"
    )
    assert private_uses(tree) == ["line 1: env._pos_to_state"]
    assert text_io_without_encoding(tree) == [
        "line 3: open('x')",
        "line 5: Path('z').read_text()",
    ]
