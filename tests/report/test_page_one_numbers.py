"""Every class of number on page 1 (the answer and Table 1) is read from its result file: each
test computes the numbers from the file with the report's own formatting and finds them in
the typeset page, so a changed result changes page 1 or fails here."""

from __future__ import annotations

import functools
import importlib.util
import json
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import typst

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("report_build_p1", ROOT / "report" / "build.py")
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)

RESULTS = ROOT / "problem2" / "results"
STUDIES = RESULTS / "studies"
MODES = ("independent", "comm", "full")
FAIL_LEVEL = 0.5  # answer.typ: independent agents without memory below this success fail


def read(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def fixed(x: float, digits: int) -> str:
    """lib.typ's ``fixed``: half away from zero, a plain hyphen for the minus sign."""
    value = Decimal(repr(x)).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP)
    return f"{value + 0:.{digits}f}".replace("-0.0", "0.0") if value != 0 else f"{0:.{digits}f}"


def pct(x: float, digits: int = 1) -> str:
    """As the report's ``pct`` (report/lib.typ): up to two more decimals where the rounded
    value would read 0 or 100 without being it (99.98 %, not 100.0 %)."""
    value, shown = 100 * x, digits
    while shown < digits + 2 and (
        (value != 0 and abs(float(fixed(value, shown))) < 10**-shown / 2)
        or (value < 100 and float(fixed(value, shown)) >= 100)
    ):
        shown += 1
    return fixed(value, shown) + " %"


def signed(x: float, digits: int = 1) -> str:
    text = fixed(100 * x, digits)
    return ("+" if x > 0 and text != fixed(0, digits) else "") + text


def plain_text(node: object) -> str:
    if isinstance(node, dict):
        own = " " if node.get("func") == "space" else node.get("text", "")
        if not isinstance(own, str):
            own = plain_text(own)
        return own + "".join(plain_text(v) for k, v in node.items() if k != "text")
    if isinstance(node, list):
        return "".join(plain_text(v) for v in node)
    return ""


@functools.cache
def page_one() -> str:
    """The answer's text and Table 1's cells as typeset, with plain spaces and hyphens."""
    text = ""
    for label in ("<answer>", "<three-cases>"):
        found = json.loads(typst.query(str(ROOT / build.MAIN), label, **build.typst_options()))
        assert len(found) == 1
        text += " " + plain_text(found[0])
    for odd, plain in (("\u2212", "-"), ("\u00a0", " "), ("\u202f", " ")):
        text = text.replace(odd, plain)
    return " ".join(text.split())


@functools.cache
def page_one_heading() -> str:
    """The answer's bold opening paragraph as typeset (it precedes the <answer> block)."""
    text = plain_text(
        json.loads(typst.query(str(ROOT / build.MAIN), "<answer-heading>", **build.typst_options()))
    )
    for odd, plain in (("\u2212", "-"), ("\u00a0", " "), ("\u202f", " ")):
        text = text.replace(odd, plain)
    return " ".join(text.split())


def test_the_assignments_map_rates_come_from_performance_json() -> None:
    main = read(RESULTS / "evaluation_results" / "performance.json")["experiments"]["main"]
    rates = [main["modes"][m]["eps"]["success_rate"]["mean"] for m in MODES]
    assert f"in {pct(min(rates))} to {pct(max(rates))} of test episodes" in page_one()
    assert f"succeed in {pct(min(rates))} or more of test episodes" in page_one_heading()
    for rate in rates:  # Table 1's first column
        assert pct(rate) in page_one()


def failing_maps() -> list[dict]:
    panel = read(STUDIES / "memory_panel" / "memory_panel.json")["maps"].values()
    return [
        m
        for m in panel
        if m["conditions"]["eps"]["success"]["independent"]["memoryless"]["mean"] < FAIL_LEVEL
    ]


def test_the_panels_gains_come_from_panel_json_and_multiplicity_json() -> None:
    panel = read(STUDIES / "panel" / "panel.json")["maps"]
    holm = read(STUDIES / "panel" / "multiplicity.json")["panel_effects"]["maps"]
    seeds = [str(m["map_seed"]) for m in failing_maps()]
    for effect, digits, words in (("distance", 1, "adds up to"), ("message", 1, "up to")):
        kept = [s for s in seeds if holm[s][effect]["rejected"] and holm[s][effect]["mean"] > 0]
        top = max(kept, key=lambda s: panel[s]["effects"]["eps"][effect]["mean"])
        gain = panel[top]["effects"]["eps"][effect]["mean"]
        assert (
            f"{effect} alone {words} {signed(gain, digits)} points (map {top})" in page_one()
            or (f"{effect} alone {words} {signed(gain, digits)} (map {top})" in page_one())
        )


def test_the_stand_in_numbers_come_from_why_json() -> None:
    panel = read(STUDIES / "panel" / "panel.json")["maps"]
    holm = read(STUDIES / "panel" / "multiplicity.json")["panel_effects"]["maps"]
    seeds = [str(m["map_seed"]) for m in failing_maps()]
    top = max(
        (s for s in seeds if holm[s]["distance"]["rejected"]),
        key=lambda s: panel[s]["effects"]["eps"]["distance"]["mean"],
    )
    why = read(STUDIES / "memory_panel" / "why" / "why.json")["maps"][top]
    stand_in = why["memoryless_channel_stand_ins_eps"]["distance"]
    changed = signed(stand_in["same_step"]["mean"])
    assert f"the distance on map {top} changes success by {changed} points" in page_one()


def words(items: list[str]) -> str:
    """lib.typ's ``join-words``: "a", "a and b", "a, b and c"."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def test_the_clock_controls_numbers_come_from_clock_json() -> None:
    """Memoryless agents with noise in the distance's place against the distance, per map."""
    study = read(STUDIES / "memory_panel" / "clock" / "clock.json")
    maps = [str(k) for k in study["protocol"]["maps"]]
    rate = {
        n: words([pct(study["maps"][k]["success"][n]["eps"]["mean"], 0) for k in maps])
        for n in ("noise", "distance")
    }
    expected = (
        f"agents succeed in {rate['noise']} on maps {words(maps)}, against {rate['distance']}"
    )
    assert expected in page_one()


def test_the_memory_numbers_come_from_memory_panel_json() -> None:
    maps = read(STUDIES / "memory_panel" / "memory_panel.json")["maps"].values()
    with_memory = [
        m["conditions"]["eps"]["success"]["independent"]["memory"]["mean"] for m in failing_maps()
    ]
    assert f"succeed in {pct(min(with_memory), 1)} or more" in page_one()
    effects = [
        m["conditions"]["eps"]["channel_effects_with_memory"][e]["mean"]
        for m in maps
        for e in ("message", "distance")
    ]
    assert f"between {signed(min(effects))} and {signed(max(effects))} points" in page_one()


LISTENER = STUDIES / "beacon_long" / "held_out" / "beacon_long_study.json"


def points_ci(stat: dict) -> str:
    low, high = (fixed(100 * x, 1) for x in stat["ci95"])
    return f"{signed(stat['mean'])} points [{low}, {high}]"


def test_the_unseen_maps_numbers_come_from_their_studies() -> None:
    one_step = read(STUDIES / "one_step_unseen" / "unseen.json")["held_out"]
    rate = pct(one_step["modes"]["independent"]["eps"]["mean"], 0)
    assert f"one step of memory succeed in {rate}" in page_one()
    # what the message costs on top of what the configuration without it sees
    unseen = one_step["differences"]
    costs = {k: signed(unseen[k]["eps"]["mean"]) for k in ("comm-independent", "full-distance")}
    assert f"comm - independent is {costs['comm-independent']} points" in page_one()
    assert f"full - distance {costs['full-distance']} points" in page_one()
    low, high = (-100 * unseen[k]["eps"]["mean"] for k in ("full-distance", "comm-independent"))
    costs = f"{fixed(min(low, high), 0)} to {fixed(max(low, high), 0)} points"
    assert f"costs agents with one step of memory {costs}" in page_one_heading()
    distance = signed(unseen["distance-independent"]["eps"]["mean"])
    assert f"The distance alone ({distance} points) is" in page_one()


def test_the_listeners_long_run_stays_off_page_one() -> None:
    """The long listener run is judged on the validation maps that also chose its checkpoints
    (a preliminary, selection-biased result): the body reports it, page 1 does not."""
    cells = read(STUDIES / "beacon_long" / "beacon_long.json")["cells"].values()
    gap = next(c for c in cells if "full_minus_independent_eps" in c)["full_minus_independent_eps"]
    low, high = (fixed(100 * x, 1) for x in gap["ci95"])
    assert f"{signed(gap['mean'])} points [{low}, {high}]" not in page_one()


def test_the_listeners_comparisons_come_from_its_held_out_study() -> None:
    """The exploratory listeners against the best independent agents of any training (the
    highest success among best_independent), and whether that interval includes 0."""
    study = read(LISTENER)
    best = max(study["best_independent"].values(), key=lambda b: b["success"]["eps"]["mean"])
    gap = best["full_minus"]["eps"]
    lead = gap["ci95"][0] > 0
    verdict = "excludes" if lead or gap["ci95"][1] < 0 else "includes"
    expected = f"{'and beat' if lead else 'but do not beat'} the best of the independent trainings"
    assert f"{expected} ({signed(gap['mean'])} points, an interval that {verdict} 0)" in page_one()
    matched = signed(study["held_out"]["differences"]["full-independent"]["eps"]["mean"])
    assert f"lead independent pairs trained the same way ({matched} points)" in page_one()
