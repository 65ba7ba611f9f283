"""Building report.pdf end to end from the generated fixture, and with inputs missing."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import build_report
import pytest
from report_inputs import Results
from report_layout import TextOp

PAGE_OBJECT = re.compile(rb"/Type\s*/Page\b(?!s)")


def pdf_page_count(path: Path) -> int:
    return len(PAGE_OBJECT.findall(path.read_bytes()))


def notes(plan: build_report.Plan) -> list[str]:
    return [op.text for page in plan.pages for op in page.ops
            if isinstance(op, TextOp) and op.text.startswith("Not available")]  # fmt: skip


@pytest.fixture(scope="module")
def built(fixture_root: Path, tmp_path_factory: pytest.TempPathFactory):
    output = tmp_path_factory.mktemp("pdf") / "report.pdf"
    plan = build_report.main(["--results", str(fixture_root), "--output", str(output)])
    return plan, output


def test_pdf_exists_with_the_planned_pages(built) -> None:
    plan, output = built
    assert output.read_bytes().startswith(b"%PDF")
    assert pdf_page_count(output) == plan.page_count
    assert 8 <= plan.page_count <= 22, plan.page_count
    assert [p.number for p in plan.pages[:2]] == [None, build_report.CONTENTS_PAGE]
    assert [p.number for p in plan.pages[1:]] == list(range(2, plan.page_count + 1))


def test_every_required_section_is_present_in_order(built) -> None:
    plan, _ = built
    titles = plan.section_titles
    assert list(build_report.REQUIRED_SECTIONS) == titles
    pages = [page for _, _, page in plan.headings]
    assert pages == sorted(pages) and pages[0] == build_report.FIRST_BODY_PAGE


def test_complete_inputs_leave_no_not_available_note(built) -> None:
    plan, _ = built
    assert notes(plan) == []


def test_the_title_page_has_blanks_for_the_student(built) -> None:
    plan, _ = built
    title = " ".join(op.text for op in plan.pages[0].ops if isinstance(op, TextOp))
    assert "Full name: ____" in title and "USC email: ____" in title


def test_numbers_come_from_the_files(fixture_root: Path) -> None:
    text = " ".join(
        op.text
        for page in build_report.plan_report(Results.under(fixture_root)).pages
        for op in page.ops
        if isinstance(op, TextOp)
    )
    assert "87.7 %" in text  # full, ε = 0.05: mean of 85, 88 and 90 in performance.json
    assert "31 sweeps" in text


def test_same_inputs_give_identical_bytes(built, fixture_root: Path, tmp_path: Path) -> None:
    _, first = built
    second = tmp_path / "again.pdf"
    build_report.main(["--results", str(fixture_root), "--output", str(second)])
    assert first.read_bytes() == second.read_bytes()
    assert b"CreationDate" not in first.read_bytes()


def test_an_empty_results_root_gives_notes_not_a_crash(tmp_path: Path) -> None:
    output = tmp_path / "empty.pdf"
    plan = build_report.main(["--results", str(tmp_path / "nothing"), "--output", str(output)])
    assert pdf_page_count(output) == plan.page_count
    assert plan.section_titles == list(build_report.REQUIRED_SECTIONS)
    assert len(notes(plan)) >= 10


@pytest.mark.parametrize(
    ("removed", "expected"),
    [
        ("problem2/results/evaluation_results", "evaluation_results/performance.json"),
        ("problem2/results/studies", "studies/per_step"),
        ("problem1/results/visualizations", "visualizations/value_heatmap.png"),
        ("problem1/results/summary.json", "problem1/results/summary.json"),
    ],
)
def test_a_missing_input_is_named_in_a_note(
    fixture_root: Path, tmp_path: Path, removed: str, expected: str
) -> None:
    root = tmp_path / "partial"
    shutil.copytree(fixture_root, root)
    target = root / removed
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    plan = build_report.plan_report(Results.under(root))
    assert plan.section_titles == list(build_report.REQUIRED_SECTIONS)
    assert any(expected in note for note in " ".join(notes(plan)).split("Not available")[1:])
