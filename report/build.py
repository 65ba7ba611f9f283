"""Typeset ``report.pdf`` (``report/report.typ``) and its companion ``report/studies.pdf``
(``report/studies.typ``) with Typst.

    python report/build.py                       # writes both PDFs, name from the README
    python report/build.py --name "Ada Lovelace" --email ada@usc.edu   # fills the README too

The student's name and email live in one place, the README's two course fields ("Full name",
"USC email"); every build reads them there, so a later plain build keeps them. ``--name`` and
``--email`` write the README's field first. Blank fields (the placeholder) build a blank cover
and print one line saying how to fill them.

The document reads the result files itself (``report/data.typ``); this script only does what
Typst cannot: it compiles with the repository as Typst's root, passes the student's name and
email as ``sys.inputs``, tells the document which optional result files exist, passes each
document the other's cross-reference entries (``<xref>`` metadata: label -> "§B.2", "Table 4"),
so that report.pdf cites the companion by section and back, and fixes the timestamp and the
fonts (Typst's embedded ones), so the same inputs give the same bytes on every machine.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import re
import sys
import time
from pathlib import Path

import typst

ROOT = Path(__file__).resolve().parent.parent


def shown(path: Path) -> str:
    """``path`` relative to the repository when inside it (console lines name no machine)."""
    path = path.resolve()
    return path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)


MAIN = Path("report") / "report.typ"  # relative to the root
STUDIES = Path("report") / "studies.typ"  # the companion
DOCUMENTS = {"report": MAIN, "studies": STUDIES}
STUDIES_PDF = ROOT / "report" / "studies.pdf"
# Result files the report uses when they exist (sys.inputs key -> path from the root).
OPTIONAL_INPUTS = {
    "reward-study": "problem2/results/studies/reward/reward_study.json",
    "map-pool-study": "problem2/results/studies/map_pool/map_pool.json",
    "stability-study": "problem2/results/studies/stability/stability.json",
    "memory-study": "problem2/results/studies/memory/memory.json",
    "memory-levers": "problem2/results/studies/memory_levers/levers.json",
    "panel-study": "problem2/results/studies/panel/panel.json",
    "panel-long": "problem2/results/studies/panel/long/panel_long.json",
    "memory-panel": "problem2/results/studies/memory_panel/memory_panel.json",
    "memory-why": "problem2/results/studies/memory_panel/why/why.json",
    "clock": "problem2/results/studies/memory_panel/clock/clock.json",
    "one-step-unseen": "problem2/results/studies/one_step_unseen/unseen.json",
    "one-step-levers": "problem2/results/studies/one_step_unseen_levers/levers.json",
    "beacon-screen": "problem2/results/studies/beacon_around/beacon_around.json",
    "beacon": "problem2/results/studies/beacon/beacon.json",
    "beacon-long": "problem2/results/studies/beacon_long/beacon_long.json",
    "beacon-long-held": "problem2/results/studies/beacon_long/held_out/beacon_long_study.json",
}


README = ROOT / "README.md"
FIELDS = {"name": "Full name", "email": "USC email"}  # flag -> the README field's label
PLACEHOLDER = "_<to be filled in by the student>_"
FILL_HINT = (
    'the cover\'s name and email are blank: fill in "Full name" and "USC email" at the top of '
    'README.md, or run: make report NAME="Your Full Name" EMAIL="you@usc.edu"'
)


def field_pattern(label: str) -> re.Pattern[str]:
    """The README line ``- **<label>:** <value>`` (value in group 2)."""
    label = re.escape(label)
    return re.compile(rf"^(- \*\*{label}:\*\*)[ \t]*(.*?)[ \t]*(\r?)$", re.MULTILINE)


def read_identity(readme: Path | None = None) -> dict[str, str]:
    """The student's name and email from the README's fields ("" where the placeholder or
    nothing stands; markdown emphasis around a value is dropped)."""
    readme = readme or README
    text = readme.read_bytes().decode("utf-8") if readme.is_file() else ""
    identity = {}
    for flag, label in FIELDS.items():
        match = field_pattern(label).search(text)
        value = match.group(2).strip("_* \t") if match else ""
        identity[flag] = "" if value.startswith("<") and value.endswith(">") else value
    return identity


def write_identity(values: dict[str, str], readme: Path | None = None) -> None:
    """Write the given fields (flag -> value; "" restores the placeholder) into the README,
    atomically; a README without the field is an error naming it."""
    readme = readme or README
    text = readme.read_bytes().decode("utf-8")
    for flag, value in values.items():
        pattern, shown = field_pattern(FIELDS[flag]), value or PLACEHOLDER
        if not pattern.search(text):
            raise ValueError(f'{readme} has no "- **{FIELDS[flag]}:**" line to fill')
        text = pattern.sub(
            lambda m, shown=shown: f"{m.group(1)} {shown}{m.group(3)}", text, count=1
        )
    temporary = readme.with_name(f".{readme.name}.tmp.{os.getpid()}")
    temporary.write_text(text, encoding="utf-8", newline="")
    os.replace(temporary, readme)


def sys_inputs(name: str = "", email: str = "", root: Path = ROOT) -> dict[str, str]:
    """The ``sys.inputs`` of the document: the student fields and the optional files found."""
    inputs = {key: path for key, path in OPTIONAL_INPUTS.items() if (root / path).is_file()}
    if name:
        inputs["name"] = name
    if email:
        inputs["email"] = email
    return inputs


@functools.cache
def cross_references(root: str) -> dict[str, str]:
    """The ``sys.inputs`` entries that let each document cite the other: ``report-xrefs`` and
    ``studies-xrefs``, each a JSON object label -> citation text ("§B.2", "Table 4"), queried
    from the document's ``<xref>`` metadata (section and table numbers do not depend on the
    other document, so one query of each suffices)."""
    inputs = sys_inputs(root=Path(root))
    found = {}
    for name, main in DOCUMENTS.items():
        try:
            entries = json.loads(
                typst.query(
                    str(Path(root) / main),
                    "<xref>",
                    root=root,
                    sys_inputs=inputs,
                    ignore_system_fonts=True,
                )
            )
        except (RuntimeError, typst.TypstError):
            continue  # the compilation itself then reports what is wrong, naming the file
        found[f"{name}-xrefs"] = json.dumps(
            {e["value"]["key"]: e["value"]["text"] for e in entries}, sort_keys=True
        )
    return found


def typst_options(name: str = "", email: str = "", root: Path = ROOT) -> dict:
    """Keyword arguments shared by ``typst.compile`` and ``typst.query`` for either document
    (the main file comes first, positionally). Typst's embedded fonts only, so the output does
    not depend on the fonts installed on the machine."""
    return {
        "root": str(root),
        "sys_inputs": sys_inputs(name, email, root) | cross_references(str(root)),
        "ignore_system_fonts": True,
    }


def build(
    output: Path, name: str = "", email: str = "", root: Path = ROOT, document: str = "report"
) -> None:
    """Compile ``document`` ("report" or "studies") into ``output`` (PDF) with a fixed
    timestamp; raises ``typst.TypstError`` on any error, e.g. a missing result file, naming
    the file."""
    options = typst_options(name, email, root)
    typst.compile(str(root / DOCUMENTS[document]), output=str(output), timestamp=0, **options)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--name", default=None, help="your full name: written into README.md, then built"
    )
    parser.add_argument(
        "--email", default=None, help="your USC email: written into README.md, then built"
    )
    parser.add_argument(
        "--output",
        type=Path,
        default=ROOT / "report.pdf",
        help="PDF to write (default: report.pdf in the repository)",
    )
    parser.add_argument(
        "--studies-output",
        type=Path,
        default=STUDIES_PDF,
        help="the companion PDF to write (default: report/studies.pdf)",
    )
    args = parser.parse_args(argv)
    for flag in FIELDS:
        if "\n" in (getattr(args, flag) or ""):
            parser.error(f"--{flag} must be one line")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    given = {
        flag: getattr(args, flag).strip() for flag in FIELDS if getattr(args, flag) is not None
    }
    if given:
        try:
            write_identity(given)
        except (OSError, ValueError) as error:
            sys.exit(f"report: could not write the name and email into the README: {error}")
    identity = read_identity()
    start = time.perf_counter()
    try:
        build(args.output, identity["name"], identity["email"])
        build(args.studies_output, identity["name"], identity["email"], document="studies")
    except typst.TypstError as error:
        sys.exit(f"report: Typst could not build the report:\n{error}")
    written = " and ".join(shown(Path(path)) for path in (args.output, args.studies_output))
    print(f"wrote {written} in {time.perf_counter() - start:.1f} s")
    if not all(identity.values()):
        print(f"report: {FILL_HINT}")


if __name__ == "__main__":
    main()
