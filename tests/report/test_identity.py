"""The student's name and email live in the README's two course fields: every build reads
them there, ``--name`` / ``--email`` (``make report NAME=.. EMAIL=..``) write them there, and
a blank cover says how to fill it. Each test works on a copy of the README."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "report_build_identity", ROOT / "report" / "build.py"
)
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)


@pytest.fixture
def readme(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the committed README with blank fields, used by build.main instead of it."""
    copy = tmp_path / "README.md"
    shutil.copyfile(ROOT / "README.md", copy)
    build.write_identity({"name": "", "email": ""}, copy)  # blank, whatever the real one holds
    assert build.read_identity(copy) == {"name": "", "email": ""}
    monkeypatch.setattr(build, "README", copy)
    return copy


@pytest.fixture
def builds(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, str]]:
    """The (name, email) of each build, recorded instead of typeset (the cover's typesetting
    is test_report.py's)."""
    done: list[tuple[str, str]] = []

    def record(output, name, email, document="report"):  # the report's build; not the companion's
        if document == "report":
            done.append((name, email))

    monkeypatch.setattr(build, "build", record)
    return done


def test_blank_fields_build_a_blank_cover_and_say_how_to_fill_them(
    readme: Path, builds: list, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    build.main(["--output", str(tmp_path / "r.pdf")])
    assert builds == [("", "")]
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("report:")]
    assert lines == [f"report: {build.FILL_HINT}"]
    assert 'make report NAME="Your Full Name" EMAIL="you@usc.edu"' in lines[0]


def test_a_name_given_once_stays_for_every_later_build(
    readme: Path, builds: list, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = readme.read_text(encoding="utf-8")
    build.main(
        ["--name", "Ada Lovelace", "--email", "ada@usc.edu", "--output", str(tmp_path / "r.pdf")]
    )
    build.main(["--output", str(tmp_path / "again.pdf")])  # a plain `make` afterwards
    assert builds == [("Ada Lovelace", "ada@usc.edu")] * 2
    assert build.FILL_HINT not in capsys.readouterr().out
    after = readme.read_text(encoding="utf-8")
    assert "- **Full name:** Ada Lovelace\n" in after and "- **USC email:** ada@usc.edu\n" in after
    changed = [
        (a, b) for a, b in zip(before.splitlines(), after.splitlines(), strict=True) if a != b
    ]
    assert len(changed) == 2  # the two fields, nothing else
    build.main(["--name", "", "--email", ""])  # back to the placeholders
    assert readme.read_text(encoding="utf-8") == before


def test_a_field_written_by_hand_is_read_and_only_the_given_one_is_replaced(
    readme: Path, builds: list, tmp_path: Path
) -> None:
    text = readme.read_text(encoding="utf-8").replace(
        "- **USC email:** _<to be filled in by the student>_", "- **USC email:** _grace@usc.edu_"
    )
    readme.write_bytes(text.replace("\n", "\r\n").encode("utf-8"))  # a Windows checkout
    assert build.read_identity() == {"name": "", "email": "grace@usc.edu"}
    build.main(["--name", "Grace Hopper", "--output", str(tmp_path / "r.pdf")])
    assert builds == [("Grace Hopper", "grace@usc.edu")]
    assert b"- **Full name:** Grace Hopper\r\n" in readme.read_bytes()
    assert b"\n" not in readme.read_bytes().replace(b"\r\n", b"")


def test_a_readme_without_the_fields_is_an_error_naming_it(readme: Path) -> None:
    readme.write_text("# no fields\n", encoding="utf-8")
    with pytest.raises(SystemExit, match='no "- \\*\\*Full name:\\*\\*" line'):
        build.main(["--name", "Ada"])
    assert readme.read_text(encoding="utf-8") == "# no fields\n"


def test_make_passes_the_name_only_when_given() -> None:
    def dry_run(*assignments: str) -> str:
        command = ["make", "-n", "-s", "report", *assignments]
        return subprocess.run(command, cwd=ROOT, capture_output=True, text=True).stdout

    assert '--name "Ada Lovelace" --email "ada@usc.edu"' in dry_run(
        "NAME=Ada Lovelace", "EMAIL=ada@usc.edu"
    )
    assert "--name" not in dry_run()
