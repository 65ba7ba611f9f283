"""No result is typed into the main text by hand: every number written as a literal in the
markup (text and equations, not code) of report.pdf is one of the assignment's givens, a
course default, a reference's year or a small integer of a formula; every other number is
computed by the report from the result files (``report/data.typ``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAIN_TEXT = (
    "report.typ",
    "answer.typ",
    "problem1.typ",
    "problem2.typ",
    "channels.typ",
    "closing.typ",
)
GIVENS = {
    "0": "formulas and ranges (V = 0, 0 to 1)",
    "1": "formulas, 'Problem 1'",
    "2": "the +2 reward, 'Problem 2', two agents",
    "3": "the 3 x 3 view",
    "5": "the 5 x 5 grid and the -5 penalty of Problem 1",
    "10": "the +10 rewards, the 10 x 10 grid, the course's replay default 10 000",
    "000": "the course's replay default 10 000",
    "11": "the 11 numbers of an observation",
    "0.1": "the -0.1 step reward",
    "50": "the 50-step episode limit of the assignment's environments (Problem 1's env)",
    "64": "the course's default hidden layer",
    "0.995": "the course skeleton's epsilon decay",
    "99": "the level of the Monte-Carlo interval (summary.json's ci99)",
    "1979": "Holm 1979",
    "1994": "Singh et al. 1994",
    "1999": "Ng et al. 1999",
    "2011": "Devlin and Kudenko 2011",
    "2015": "Mnih et al. 2015",
    "2016": "Bellemare et al. 2016, Foerster et al. 2016, van Hasselt et al. 2016",
    "2017": "Florensa et al. 2017",
    "2018": "Sutton and Barto 2018",
    "2019": "Eccles et al. 2019, Lowe et al. 2019",
}

STATEMENTS = ("let", "set", "show", "import", "include")
IDENT = re.compile(r"[A-Za-z_][\w-]*")
NUMBER = re.compile(r"\d+(?:\.\d+)?")
CLOSERS = {"(": ")", "{": "}"}


class MarkupNumbers:
    """Typst source scanned as Typst reads it: markup (where text is typeset), code after
    ``#`` (skipped, except the content blocks ``[...]`` inside it) and math (scanned like
    markup). ``found`` lists (line, number) of every number literal in markup or math."""

    def __init__(self, source: str) -> None:
        self.s = source
        self.found: list[tuple[int, str]] = []
        self.markup(0)

    def line(self, i: int) -> int:
        return self.s.count("\n", 0, i) + 1

    def after_comment(self, i: int) -> int | None:
        """Where the comment starting at ``i`` ends (a line comment: at its newline), or
        None if no comment starts there."""
        if self.s.startswith("//", i):
            end = self.s.find("\n", i)
            return len(self.s) if end < 0 else end
        if self.s.startswith("/*", i):
            return self.s.index("*/", i) + 2
        return None

    def markup(self, i: int, closer: str | None = None) -> int:
        """Markup (``closer`` "]") or math (``closer`` "$") from ``i``; returns the index
        after its closer."""
        s, depth = self.s, 0
        while i < len(s):
            c = s[i]
            if (after := self.after_comment(i)) is not None:
                i = after
            elif c == "\\":
                i += 2
            elif c == "`":
                ticks = re.match(r"`+", s[i:]).group()
                i = s.index(ticks, i + len(ticks)) + len(ticks)
            elif c == "$":
                if closer == "$":
                    return i + 1
                i = self.markup(i + 1, "$")
            elif c == "#":
                i = self.hash_expression(i + 1)
            elif c in "@<" and closer != "$" and IDENT.match(s, i + 1):  # a reference or label
                i = IDENT.match(s, i + 1).end() + (c == "<")
            elif c in "[]":
                if c == "]" and depth == 0 and closer == "]":
                    return i + 1
                depth += 1 if c == "[" else -1
                i += 1
            elif c.isdigit() and not (s[i - 1].isalnum() or s[i - 1] == "_"):
                number = NUMBER.match(s, i)
                self.found.append((self.line(i), number.group()))
                i = number.end()
            else:
                i += 1
        return i

    def code(self, i: int, closer: str | None, statement: bool = False) -> int:
        """Code up to ``closer`` (returns the index after it) or, for a ``statement``, to
        its end: a newline or ``;`` at depth 0, or the ``]`` of the block around it."""
        s = self.s
        while i < len(s):
            c = s[i]
            if (after := self.after_comment(i)) is not None:
                i = after
            elif c == '"':
                i += 1
                while s[i] != '"':
                    i += 2 if s[i] == "\\" else 1
                i += 1
            elif c == "[":
                i = self.markup(i + 1, "]")
            elif c == "$":
                i = self.markup(i + 1, "$")
            elif c in CLOSERS:
                i = self.code(i + 1, CLOSERS[c])
            elif c == closer:
                return i + 1
            elif statement and c in "\n;]":
                return i + (c == ";")
            elif c in ")}]":
                raise ValueError(f"unbalanced {c!r} on line {self.line(i)}")
            else:
                i += 1
        return i

    def block(self, i: int) -> int:
        """The ``[content]`` or ``{code}`` block at ``i`` (after spaces)."""
        i = self.skip_spaces(i)
        if self.s[i] == "[":
            return self.markup(i + 1, "]")
        if self.s[i] == "{":
            return self.code(i + 1, "}")
        raise ValueError(f"a block expected on line {self.line(i)}")

    def skip_spaces(self, i: int) -> int:
        while i < len(self.s) and self.s[i] in " \t\n":
            i += 1
        return i

    def condition(self, i: int) -> int:
        """The code of an ``if``/``for``/``while`` head, up to its block."""
        while self.s[i] not in "[{":
            if self.s[i] == "(":
                i = self.code(i + 1, ")")
            elif self.s[i] == '"':
                i = self.s.index('"', i + 1) + 1
            else:
                i += 1
        return i

    def hash_expression(self, i: int) -> int:
        """The expression after a ``#``; returns where markup resumes."""
        word = IDENT.match(self.s, i)
        name = word.group() if word else ""
        if name in STATEMENTS:
            return self.code(word.end(), None, statement=True)
        if name in ("for", "while"):
            return self.block(self.condition(word.end()))
        if name == "if":
            i = self.block(self.condition(word.end()))
            after = self.skip_spaces(i)
            while self.s.startswith("else", after):
                after = self.skip_spaces(after + 4)
                if self.s.startswith("if", after):
                    after = self.condition(after + 2)
                i = self.block(after)
                after = self.skip_spaces(i)
            return i
        if name == "context":
            return self.hash_expression(self.skip_spaces(word.end()))
        return self.postfix(word.end() if word else i)

    def postfix(self, i: int) -> int:
        """Calls, trailing content blocks and field accesses after an identifier."""
        s = self.s
        while i < len(s):
            if s[i] in CLOSERS:
                i = self.code(i + 1, CLOSERS[s[i]])
            elif s[i] == "[":
                i = self.markup(i + 1, "]")
            elif s[i] == "." and IDENT.match(s, i + 1):
                i = IDENT.match(s, i + 1).end()
            else:
                return i
        return i


def test_the_scanner_finds_numbers_in_text_and_math_but_not_in_code() -> None:
    source = (
        "#let x = 0.25  // 7\n"
        "Success 99.8 %, #pct(x, digits: 1) of $gamma = 0.95$ #if x > 3 [in 12] else [out 4]\n"
        "#for m in (1, 2) [map #m: 5]. Table2 and @fig-3 <label-4>; `raw 6` \\7 /* 8 */ #f.g[9]"
    )
    found = MarkupNumbers(source).found
    assert [n for _, n in found] == ["99.8", "0.95", "12", "4", "5", "9"]
    assert [line for line, _ in found] == [2, 2, 2, 2, 3, 3]


@pytest.mark.parametrize("name", MAIN_TEXT)
def test_the_main_text_types_no_result_by_hand(name: str) -> None:
    found = MarkupNumbers((ROOT / "report" / name).read_text(encoding="utf-8")).found
    assert [(line, number) for line, number in found if number not in GIVENS] == []
