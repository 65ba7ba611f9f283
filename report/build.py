"""Typeset ``report.pdf`` from ``report/report.typ`` with Typst.

    python report/build.py                                  # writes report.pdf (blank name)
    python report/build.py --name "Ada Lovelace" --email ada@usc.edu --output my_report.pdf

The document reads the result files itself (``report/data.typ``); this script only does what
Typst cannot: it compiles with the repository as Typst's root, passes the student's name and
email as ``sys.inputs``, tells the document which optional result files exist, and fixes the
timestamp and the fonts (Typst's embedded ones), so the same inputs give the same bytes on
every machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import typst

ROOT = Path(__file__).resolve().parent.parent
MAIN = Path("report") / "report.typ"  # relative to the root
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
    "one-step-unseen": "problem2/results/studies/one_step_unseen/unseen.json",
    "one-step-levers": "problem2/results/studies/one_step_unseen_levers/levers.json",
}


def sys_inputs(name: str = "", email: str = "", root: Path = ROOT) -> dict[str, str]:
    """The ``sys.inputs`` of the document: the student fields and the optional files found."""
    inputs = {key: path for key, path in OPTIONAL_INPUTS.items() if (root / path).is_file()}
    if name:
        inputs["name"] = name
    if email:
        inputs["email"] = email
    return inputs


def typst_options(name: str = "", email: str = "", root: Path = ROOT) -> dict:
    """Keyword arguments shared by ``typst.compile`` and ``typst.query`` for this report
    (the main file comes first, positionally). Typst's embedded fonts only, so the output does
    not depend on the fonts installed on the machine."""
    return {
        "root": str(root),
        "sys_inputs": sys_inputs(name, email, root),
        "ignore_system_fonts": True,
    }


def build(output: Path, name: str = "", email: str = "", root: Path = ROOT) -> None:
    """Compile the report into ``output`` (PDF) with a fixed timestamp; raises
    ``typst.TypstError`` on any error, e.g. a missing result file, naming the file."""
    options = typst_options(name, email, root)
    typst.compile(str(root / MAIN), output=str(output), timestamp=0, **options)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--name", default="", help="your full name for the cover (default: blank)")
    parser.add_argument("--email", default="", help="your USC email for the cover (default: blank)")
    parser.add_argument(
        "--output",
        type=Path,
        default=ROOT / "report.pdf",
        help="PDF to write (default: report.pdf in the repository)",
    )
    args = parser.parse_args(argv)
    for flag in ("name", "email"):
        if "\n" in getattr(args, flag):
            parser.error(f"--{flag} must be one line")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    start = time.perf_counter()
    try:
        build(args.output, args.name, args.email)
    except typst.TypstError as error:
        sys.exit(f"report: Typst could not build the report:\n{error}")
    print(f"wrote {args.output} in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
