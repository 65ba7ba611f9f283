"""The report and its companion compile from the committed results, keep their blanks, are
reproducible, and have the report's shape: at most 12 pages numbered from the cover, the
assignment's eleven items as headings in its order, the companion cited by section."""

from __future__ import annotations

import functools
import importlib.util
import io
import json
import shutil
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import typst

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("report_build", ROOT / "report" / "build.py")
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)


def cover_field(label: str, name: str = "", email: str = "") -> str:
    """The text typeset in the cover field ``label`` (``student-name`` / ``student-email``)."""
    found = json.loads(
        typst.query(str(ROOT / build.MAIN), f"<{label}>", **build.typst_options(name, email))
    )
    assert len(found) == 1, f"one cover field {label} expected"

    def text(node) -> str:
        if isinstance(node, dict):
            return node.get("text", "") + "".join(text(v) for k, v in node.items() if k != "text")
        if isinstance(node, list):
            return "".join(text(v) for v in node)
        return ""

    return text(found[0]["body"]).strip()


@pytest.fixture(scope="module")
def blank_pdf(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    output = tmp_path_factory.mktemp("report") / "report.pdf"
    build.build(output)
    return output.read_bytes()


def test_report_compiles_from_the_committed_results_without_warnings() -> None:
    pdf, warnings = typst.compile_with_warnings(str(ROOT / build.MAIN), **build.typst_options())
    assert pdf.startswith(b"%PDF")
    assert [w.message for w in warnings] == []


def test_report_is_byte_identical_across_builds(blank_pdf: bytes, tmp_path: Path) -> None:
    build.build(tmp_path / "again.pdf")
    assert (tmp_path / "again.pdf").read_bytes() == blank_pdf


def test_cover_fields_are_blank_by_default() -> None:
    assert cover_field("student-name") == ""
    assert cover_field("student-email") == ""


def test_name_and_email_appear_on_the_cover_when_given(blank_pdf: bytes, tmp_path: Path) -> None:
    name, email = "Ada Lovelace-Byron", "ada@usc.edu"
    assert cover_field("student-name", name, email) == name
    assert cover_field("student-email", name, email) == email
    build.build(tmp_path / "named.pdf", name, email)
    assert (tmp_path / "named.pdf").read_bytes() != blank_pdf


def test_a_missing_result_file_is_an_error_naming_it(tmp_path: Path) -> None:
    shutil.copytree(ROOT / "report", tmp_path / "report", ignore=shutil.ignore_patterns("*.py*"))
    shutil.copytree(ROOT / "problem1" / "results", tmp_path / "problem1" / "results")
    with pytest.raises(typst.TypstError, match="hyperparameters.json"):
        build.build(tmp_path / "report.pdf", root=tmp_path)
    assert not (tmp_path / "report.pdf").exists()


def test_optional_inputs_are_passed_only_when_present(tmp_path: Path) -> None:
    assert "reward-study" not in build.sys_inputs(root=tmp_path)
    study = tmp_path / build.OPTIONAL_INPUTS["reward-study"]
    study.parent.mkdir(parents=True)
    study.write_text("{}", encoding="utf-8")
    assert build.sys_inputs(root=tmp_path)["reward-study"] == build.OPTIONAL_INPUTS["reward-study"]
    assert "name" not in build.sys_inputs(root=tmp_path)


def test_cli_refuses_a_name_on_two_lines(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        build.parse_args(["--name", "Ada\nLovelace"])
    assert exit_info.value.code == 2
    assert "--name must be one line" in capsys.readouterr().err


def test_the_reward_study_is_typeset_from_its_results_file() -> None:
    assert (ROOT / build.OPTIONAL_INPUTS["reward-study"]).is_file()
    for main, label in ((build.MAIN, "<reward-row>"), (build.STUDIES, "<reward-table>")):
        found = json.loads(typst.query(str(ROOT / main), label, **build.typst_options()))
        assert len(found) == 1


@functools.cache
def marker_pages() -> dict[str, list[int]]:
    """Label -> the physical pages of the document's metadata markers so labelled, in
    document order (one compilation for every test that reads them)."""
    found = json.loads(typst.query(str(ROOT / build.MAIN), "metadata", **build.typst_options()))
    pages: dict[str, list[int]] = {}
    for marker in found:
        pages.setdefault(marker.get("label", "").strip("<>"), []).append(marker["value"])
    return pages


def page_of(label: str) -> int:
    """The physical page on which the document's metadata ``label`` stands."""
    found = marker_pages().get(label, [])
    assert len(found) == 1, f"one {label} marker expected"
    return found[0]


# The assignment's items, in its order: Problem 1's five, then Problem 2's six.
ASSIGNMENT_ITEMS = (
    "Iterations to convergence",
    "Value function",
    "Optimal policy",
    "Convergence of Value Iteration and Q-Iteration",
    "How the stochastic transitions shape the optimal policy",
    "Training hyperparameters",
    "Training curves",
    "Final success rates",
    "Comparison across configurations",
    "How distance information and communication affect coordination",
    "Learned strategies",
)


def plain_text(node: object) -> str:
    """The text of a queried element tree, spaces kept."""
    if isinstance(node, dict):
        own = " " if node.get("func") == "space" else node.get("text", "")
        if not isinstance(own, str):
            own = plain_text(own)
        return own + "".join(plain_text(v) for k, v in node.items() if k != "text")
    if isinstance(node, list):
        return "".join(plain_text(v) for v in node)
    return ""


@functools.cache
def page_numbers() -> list[dict[str, int]]:
    return [
        marker["value"]
        for marker in json.loads(
            typst.query(str(ROOT / build.MAIN), "<page-number>", **build.typst_options())
        )
    ]


def test_report_pdf_has_at_most_12_pages(blank_pdf: bytes) -> None:
    pages = page_numbers()
    assert 8 <= len(pages) <= 12
    assert blank_pdf.count(b"/Type /Page\n") in (0, len(pages))  # the PDF agrees, if it says


def test_printed_page_numbers_equal_pdf_page_numbers_from_the_cover() -> None:
    pages = page_numbers()
    assert [p["physical"] for p in pages] == list(range(1, len(pages) + 1))
    assert [p["printed"] for p in pages] == [p["physical"] for p in pages]


def test_the_eleven_items_are_headings_in_the_assignments_order() -> None:
    headings = [
        plain_text(h["body"]).strip()
        for h in json.loads(typst.query(str(ROOT / build.MAIN), "heading", **build.typst_options()))
    ]
    found = [h for h in headings if h in ASSIGNMENT_ITEMS]
    assert found == list(ASSIGNMENT_ITEMS)
    problem2 = next(i for i, h in enumerate(headings) if h.startswith("Problem 2"))
    assert all(headings.index(item) < problem2 for item in ASSIGNMENT_ITEMS[:5])
    assert all(headings.index(item) > problem2 for item in ASSIGNMENT_ITEMS[5:])
    for section in ("What departs from the assignment, and why", "Limitations", "References"):
        assert section in headings


def test_the_companion_builds_without_warnings_and_is_reproducible(tmp_path: Path) -> None:
    pdf, warnings = typst.compile_with_warnings(str(ROOT / build.STUDIES), **build.typst_options())
    assert pdf.startswith(b"%PDF")
    assert [w.message for w in warnings] == []
    build.build(tmp_path / "studies.pdf", document="studies")
    build.build(tmp_path / "again.pdf", document="studies")
    assert (tmp_path / "studies.pdf").read_bytes() == (tmp_path / "again.pdf").read_bytes()


@pytest.mark.parametrize("document", ["report", "studies"])
def test_every_cross_reference_between_the_documents_resolves(document: str) -> None:
    main = ROOT / build.DOCUMENTS[document]
    assert json.loads(typst.query(str(main), "<xref-missing>", **build.typst_options())) == []


def test_the_report_cites_the_companion_by_section() -> None:
    sections = json.loads(build.typst_options()["sys_inputs"]["studies-xrefs"])
    text = "".join(
        plain_text(p)
        for p in json.loads(typst.query(str(ROOT / build.MAIN), "par", **build.typst_options()))
    )
    cited = {v for v in sections.values() if v.startswith("§") and f"companion {v}" in text}
    assert len(cited) >= 10


def test_the_answer_to_the_question_ends_on_the_first_page() -> None:
    assert page_of("answer-end") == 1


def test_no_table_splits_across_pages() -> None:
    tops, bottoms = marker_pages()["table-top"], marker_pages()["table-bottom"]
    assert len(tops) == len(bottoms) >= 8
    assert [(t, b) for t, b in zip(tops, bottoms, strict=True) if t != b] == []


def test_no_table_of_the_companion_splits_across_pages() -> None:
    found = json.loads(typst.query(str(ROOT / build.STUDIES), "metadata", **build.typst_options()))
    tops = [m["value"] for m in found if m.get("label") == "<table-top>"]
    bottoms = [m["value"] for m in found if m.get("label") == "<table-bottom>"]
    assert len(tops) == len(bottoms) > 10
    assert [(t, b) for t, b in zip(tops, bottoms, strict=True) if t != b] == []


def test_no_page_of_the_main_part_but_its_last_ends_in_its_upper_part() -> None:
    """Rendered, every main page but the last carries text or figures down to at least 70 %
    of its height (above the bottom margin and its page number)."""
    options = {k: v for k, v in build.typst_options().items() if k != "format"}
    pages = typst.compile(str(ROOT / build.MAIN), format="png", ppi=20, **options)
    start, end = page_of("main-start"), page_of("main-end")
    assert start == 2  # the cover with the answer is page 1
    filled = {}
    for number in range(start, end):
        grey = matplotlib.image.imread(io.BytesIO(pages[number - 1]), format="png")[..., :3]
        height = grey.shape[0]
        body = grey[: int(height * (1 - 2.2 / 29.7))].mean(axis=2)  # style.typ: bottom 2.2 cm
        inked = np.flatnonzero((body < 0.9).any(axis=1))
        filled[number] = (inked.max() + 1) / height
    assert {n: round(f, 2) for n, f in filled.items() if f < 0.7} == {}


def test_page_one_answers_in_at_most_400_words() -> None:
    """The answer's words as typeset (numbers count as words, a reference as one)."""
    found = json.loads(typst.query(str(ROOT / build.MAIN), "<answer>", **build.typst_options()))
    assert len(found) == 1

    def text(node: object) -> str:
        if isinstance(node, dict):
            if node.get("func") == "ref":
                return " reference "
            own = " " if node.get("func") == "space" else node.get("text", "")
            return own + "".join(text(v) for k, v in node.items() if k != "text")
        if isinstance(node, list):
            return " ".join(text(v) for v in node)
        return ""

    words = [w for w in text(found[0]).split() if any(c.isalnum() for c in w)]
    assert 150 <= len(words) <= 400


def test_the_companions_tables_and_figures_are_numbered_apart_from_the_reports() -> None:
    """The companion's tables and figures read "Table S5", "Figure S2", so that "companion
    Table S5" cannot be taken for the report's own Table 5."""
    entries = json.loads(build.typst_options()["sys_inputs"]["studies-xrefs"]).values()
    numbered = [v for v in entries if v.startswith(("Table", "Figure"))]
    assert numbered and all(v.split(" ", 1)[1].startswith("S") for v in numbered)
