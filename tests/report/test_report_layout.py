"""The layout engine keeps every line inside the text area and tables on the page."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from report_layout import (
    MARGIN_BOTTOM,
    MARGIN_X,
    PAGE_HEIGHT,
    TEXT_WIDTH,
    Heading,
    Paragraph,
    Table,
    TextOp,
    layout,
    text_width,
    wrap,
)

WORDS = st.text(alphabet="abcdefghijklmnopqrstuvwxyzγε→ 0123456789", min_size=0, max_size=40)


@settings(max_examples=40, deadline=None)
@given(st.lists(WORDS, min_size=1, max_size=30), st.floats(0.5, 6.0))
def test_wrapped_lines_fit_and_keep_the_words(words: list[str], width: float) -> None:
    text = " ".join(words)
    lines = wrap(text, width, 10)
    assert all(text_width(line, 10) <= width + 1e-9 for line in lines if len(line) > 1)
    assert "".join(lines).replace(" ", "") == text.replace(" ", "")


def test_a_long_table_splits_with_its_header_repeated_and_stays_on_the_page() -> None:
    rows = tuple((str(k), "a fairly long cell text " * 3, f"{k:.2f}") for k in range(120))
    laid = layout([Heading("T"), Table(("index", "text", "value"), rows, (1, 4, 1))])
    assert len(laid.pages) >= 3
    for page in laid.pages:
        texts = [op for op in page.ops if isinstance(op, TextOp)]
        assert any(op.text == "index" for op in texts)  # header on every page
        assert all(op.y <= PAGE_HEIGHT - MARGIN_BOTTOM for op in texts)
        assert all(MARGIN_X <= op.x <= MARGIN_X + TEXT_WIDTH for op in texts)


def test_level_one_headings_start_pages_and_are_listed() -> None:
    laid = layout([Heading("A", 1), Paragraph("x"), Heading("B", 1), Heading("b", 2)], 5)
    assert [(t, page) for t, _, page in laid.headings] == [("A", 5), ("B", 6), ("b", 6)]
