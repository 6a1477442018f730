"""No hand-typed figure in README.md, docs/*.md or models/README.md: every measured figure is marked with the JSON file
and key it comes from and equals that value as formatted; every generated table equals what its
report script prints from its JSON; and no number with a unit of measurement stands in prose
unmarked, unless it is a design constant on docs/figures.py's allow-list. The mechanism, and how to
update the docs after a re-measurement, are in docs/figures.py and docs/testing.md."""

from __future__ import annotations

import importlib.util
import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "docs" / "figures.py")
figures = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = figures  # its dataclasses look their module up while it loads
_spec.loader.exec_module(figures)

DOCS = figures.documents(ROOT)
IDS = [str(d.relative_to(ROOT)) for d in DOCS]


@pytest.mark.parametrize("doc", DOCS, ids=IDS)
def test_every_marked_figure_equals_its_json(doc):
    problems = figures.check_marks(doc, ROOT)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("doc", DOCS, ids=IDS)
def test_every_generated_table_equals_what_its_report_script_prints(doc):
    problems = figures.check_blocks(doc, ROOT)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("doc", DOCS, ids=IDS)
def test_no_measurement_in_prose_is_unmarked(doc):
    problems = figures.check_prose(doc, ROOT)
    assert not problems, "numbers with a unit that are neither marked nor allowed:\n" + "\n".join(problems)


def test_the_docs_quote_data_at_all():
    """The checks above pass vacuously on documents without marks: the docs must quote through them."""
    text = "".join(d.read_text() for d in DOCS)
    assert len(figures.MARK_RE.findall(text)) >= 100
    assert len(figures.BLOCK_RE.findall(text)) >= 10


def test_every_allowed_constant_says_why_and_is_still_needed():
    prose = "\n".join(figures.prose(d.read_text()) for d in DOCS)
    for pattern, why in figures.ALLOWED:
        re.compile(pattern)
        assert len(why) >= 30 and not why.endswith("."), (pattern, why)
        assert re.search(pattern, prose), f"allow-list entry no longer used by any document: {pattern!r}"


def _copy(tmp_path: Path, doc: Path, text: str) -> Path:
    out = tmp_path / doc.name
    out.write_text(text)
    return out


def test_a_hand_edited_figure_fails(tmp_path):
    readme = ROOT / "README.md"
    text = readme.read_text()
    mk = figures.marks(readme, text)[0]
    edited = str(int(mk.text[-1]) ^ 1)  # change the last digit: 0↔1, 2↔3, ...
    doc = _copy(tmp_path, readme, text[: mk.end - 1] + edited + text[mk.end :])
    problems = figures.check_marks(doc, ROOT)
    assert len(problems) == 1 and "the JSON says" in problems[0], problems


def test_a_hand_edited_generated_table_fails(tmp_path):
    page = ROOT / "docs" / "robustness.md"
    text = page.read_text()
    block = figures.blocks(page, text)[0]
    cell = re.search(r"\| (\d+) %", block.body)  # the first success rate in the table
    at = block.start + cell.start(1)
    edited = text[:at] + ("99" if cell.group(1) != "99" else "98") + text[at + len(cell.group(1)) :]
    problems = figures.check_blocks(_copy(tmp_path, page, edited), ROOT)
    assert len(problems) == 1 and "generated block differs" in problems[0], problems


def test_a_figure_typed_into_prose_is_found_and_a_design_constant_is_not(tmp_path):
    doc = tmp_path / "page.md"
    doc.write_text(
        "The loop ran at 2,400 steps/s, 3.2× faster, and held 12.5 cm (0.49–0.53 M steps).\n"
        "Success is an error within 5 cm over the last 2 s; `--total-steps 2000000` and `7 cm` in code.\n"
        "Quoted: 12.5<!--= docs/bench/sitl_speed.json#benchmarks/0/extra_info/steps_per_round :d--> cm.\n"
    )
    found = [(u.line, u.text) for u in figures.unmarked(doc)]
    assert found == [(1, "2,400"), (1, "3.2"), (1, "12.5"), (1, "0.49"), (1, "0.53")]


def test_marks_walk_keys_lists_filters_and_reductions(tmp_path):
    data = {
        "runs": {
            "a": {"group": "x", "err_m": 0.0123, "rows": [{"u": 1, "v": 0.5}, {"u": 2, "v": None}, {"u": 3, "v": 1.5}]},
            "b": {"group": "x", "err_m": 0.0321, "rows": []},
            "c": {"group": "y", "err_m": 0.5, "rows": []},
        },
        "bench": [{"name": "t[a-b]", "us": 6.831}, {"name": "t[c]", "us": 40.0}],
        "key with spaces": {"n": 491520},
    }
    (tmp_path / "d.json").write_text(json.dumps(data))
    src = {"d": "d.json"}
    cases = {
        "d#runs/a/err_m *100:.2f": "1.23",
        "d#runs/*/group=x/err_m mean*100:.1f": "2.2",
        "d#runs/*/group!=x/err_m max:.1f": "0.5",
        "d#runs/*/err_m>=0.02/err_m len:d": "2",
        "d#runs/a/rows/*/v min:.1f": "0.5",  # the blank cell (None) is not a value
        "d#runs/a/rows/*/v p50:.1f": "1.0",
        "d#runs/a/rows/-1/u :d": "3",
        "d#runs/a/rows/*/v>=1/u min:d": "3",
        "d#bench/name=t[a-b]/us :.2f": "6.83",
        "d#key with spaces/n /1e6:.2f": "0.49",
        "d#key with spaces/n :,d": "491,520",
    }
    for ref, want in cases.items():
        assert figures.resolve(ref, src, tmp_path) == want, ref
    for bad in ("d#runs/z/err_m :.1f", "d#runs/*/err_m :.1f", "d#runs/a/group :.1f", "d#runs/a/err_m %.1f"):
        with pytest.raises(figures.FigureError):
            figures.resolve(bad, src, tmp_path)


def test_a_figure_of_blanks_is_an_error_but_a_dash_for_a_short_run(tmp_path, monkeypatch):
    """Every selected value blank (None: a short-trained policy crashed every episode) fails the
    update, unless the documentation's commands are being run short (QUADPILOT_DOCS_QUICK)."""
    from quadpilot.console import QUICK_ENV

    (tmp_path / "d.json").write_text(json.dumps({"rows": [{"v": None}, {"v": None}]}))
    ref, src = "d#rows/*/v max*100:.1f", {"d": "d.json"}
    monkeypatch.delenv(QUICK_ENV, raising=False)
    with pytest.raises(figures.FigureError, match="no value"):
        figures.resolve(ref, src, tmp_path)
    monkeypatch.setenv(QUICK_ENV, "1")
    assert figures.resolve(ref, src, tmp_path) == "–"
