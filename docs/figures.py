"""Measured figures in README.md, docs/*.md and models/README.md come from committed JSON files: this module finds
them, checks them against their JSON, and rewrites them after a re-measurement.

    .venv/bin/python docs/figures.py check            # what tests/docs/test_figures.py checks
    .venv/bin/python docs/figures.py update           # rewrite every marked figure and generated block
    .venv/bin/python docs/figures.py unmarked FILE.md # the figure-like numbers of one file not yet marked

Three things in the Markdown:

1. A **marked figure**: the number as printed, then an HTML comment naming where it comes from,

       holds 0.32<!--= dr#nominal/mean_error_last_window_m *100:.2f--> cm

   `<!--= SOURCE#PATH FORMAT-->`. SOURCE is a JSON file relative to the repository root, or an alias
   declared anywhere in the same Markdown file with `<!-- figure sources: dr=models/hover_dr/eval.json
   lat=docs/bench/policy_latency.json -->`. PATH walks the JSON with `/`: a dict key (spaces allowed),
   a list index, `FIELD=VALUE` (the one list element whose FIELD, itself a `.`-path, equals VALUE),
   or `*` (every element or dict value; then FORMAT starts with a reduction). After a `*`, a segment
   `FIELD=VALUE`, `FIELD!=VALUE` or `FIELD>=NUMBER` (also `<=`, `>`, `<`) keeps only the values that
   pass (`len` then counts them). FORMAT is
   `[REDUCTION][*SCALE|/SCALE]:SPEC`: REDUCTION one of mean, min, max, sum, len, or pNN (the NN-th
   percentile, interpolated as NumPy's default) over the `*` values (blank cells, null, skipped),
   SCALE a number the value is multiplied or divided by (100 for a fraction printed as a percentage,
   100 for metres printed in cm), SPEC a Python format spec (`.2f`, `,.0f`, `d`). The printed text
   must equal `format(value, SPEC)`, with "−" read as "-".

2. A **generated block**: Markdown written by a report script from a JSON file,

       <!-- BEGIN generated: benchmarks/report_sitl.py docs/bench/sitl_speed.json --table speed -->
       ...
       <!-- END generated -->

   The block must equal the script's standard output (run from the repository root with this
   Python; blank lines at either end ignored).

3. A **constants block**: a table of parameter values (a noise model's data-sheet figures, say),
   none of them measured here,

       <!-- BEGIN constants: the noise model's parameters, each with its source in the table -->
       ...
       <!-- END constants -->

   The reason after `constants:` is required. Nothing inside is checked.

4. Everything else is **prose**, and a number in it followed by a unit of measurement (%, cm, m, s,
   ms, µs, steps/s, ×, ...) is a figure that must be marked, unless it is a design constant on the
   allow-list below (each entry says why it is not a measurement). Code spans, fenced code (except
   `#` comments in it), link targets, HTML comments and LaTeX are not prose.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import runpy
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def documents(root: Path = ROOT) -> list[Path]:
    """The Markdown files whose figures are checked: README.md, docs/*.md and models/README.md."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md")), root / "models" / "README.md"]


# ---------------------------------------------------------------------------------------------
# Marked figures

NUMBER = r"[-−+]?\d[\d,]*(?:\.\d+)?(?:e[-−+]?\d+)?"
MARK_RE = re.compile(rf"(?P<text>{NUMBER})<!--=[ \t]*(?P<ref>[^\n]*?)[ \t]*-->")
SOURCES_RE = re.compile(r"<!--\s*figure sources:(?P<body>.*?)-->", re.S)
FORMAT_RE = re.compile(
    r"^(?P<reduce>mean|min|max|sum|len|p\d{1,2})?(?:(?P<op>[*/])(?P<scale>[\d.e+-]+))?:(?P<spec>.*)$"
)


def _percentile(values: list, q: float) -> float:
    """The q-th percentile with linear interpolation between order statistics (NumPy's default)."""
    v = sorted(values)
    pos = (len(v) - 1) * q / 100
    lo = math.floor(pos)
    hi = min(lo + 1, len(v) - 1)
    return v[lo] + (v[hi] - v[lo]) * (pos - lo)


REDUCERS = {
    "mean": lambda v: math.fsum(v) / len(v),
    "min": min,
    "max": max,
    "sum": math.fsum,
    "len": len,
}


class FigureError(ValueError):
    """A mark that cannot be resolved: unknown source, missing key, bad format."""


@dataclass(frozen=True)
class Mark:
    doc: Path
    line: int
    start: int  # offset of the printed number in the document
    end: int  # offset just after the printed number
    text: str  # the number as printed
    ref: str  # what is inside the comment


def aliases(text: str) -> dict[str, str]:
    """The `figure sources:` declarations of one document: alias → JSON path (repository root)."""
    out: dict[str, str] = {}
    code = _in_code(text)
    for m in SOURCES_RE.finditer(text):
        if any(a <= m.start() < b for a, b in code):
            continue
        for item in m.group("body").split():
            name, sep, path = item.partition("=")
            if not sep or not name or not path:
                raise FigureError(f"figure sources: expected NAME=PATH, got {item!r}")
            out[name] = path
    return out


def _in_code(text: str) -> list[tuple[int, int]]:
    """Spans of fenced code and code spans: a mark written there is an example, not a figure."""
    spans = [m.span() for m in re.finditer(r"^(```|~~~).*?^\1[ \t]*$", text, re.S | re.M)]
    spans += [m.span() for m in re.finditer(r"`[^`\n]*`", text)]
    return spans


def marks(doc: Path, text: str | None = None) -> list[Mark]:
    text = doc.read_text() if text is None else text
    code = _in_code(text)
    return [
        Mark(doc, text.count("\n", 0, m.start()) + 1, m.start(), m.end("text"), m.group("text"), m.group("ref"))
        for m in MARK_RE.finditer(text)
        if not any(a <= m.start() < b for a, b in code)
    ]


def _walk(node, path: str, where: str):
    """The value (or, after a `*`, the list of values) at `path` in a parsed JSON document."""
    nodes, spread = [node], False
    for seg in path.split("/"):
        nxt = []
        for n in nodes:
            if seg == "*":
                nxt.extend(n.values() if isinstance(n, dict) else n)
                spread = True
            elif spread and FILTER_RE.match(seg):  # after a `*`: keep the values that pass
                f = FILTER_RE.match(seg)
                if _passes(_get(n, f.group("field")), f.group("op"), f.group("value")):
                    nxt.append(n)
            elif isinstance(n, dict):
                if seg not in n:
                    raise FigureError(f"{where}: no key {seg!r} (keys: {', '.join(list(n)[:12])})")
                nxt.append(n[seg])
            elif isinstance(n, list) and "=" in seg:
                field, _, want = seg.partition("=")
                hits = [e for e in n if str(_get(e, field)) == want]
                if len(hits) != 1:
                    raise FigureError(f"{where}: {len(hits)} list elements with {field} = {want!r}, expected 1")
                nxt.append(hits[0])
            elif isinstance(n, list) and re.fullmatch(r"-?\d+", seg):
                nxt.append(n[int(seg)])
            else:
                raise FigureError(f"{where}: cannot apply {seg!r} to a {type(n).__name__}")
        nodes = nxt
    return nodes if spread else nodes[0]


FILTER_RE = re.compile(r"^(?P<field>[^=<>!]+?)(?P<op>>=|<=|!=|=|>|<)(?P<value>.*)$")


def _passes(value, op: str, want: str) -> bool:
    """A filter segment's test: `=` and `!=` compare text (str(value)), the others numbers."""
    if op in ("=", "!="):
        return (str(value) == want) == (op == "=")
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    w = float(want)
    return {">=": value >= w, "<=": value <= w, ">": value > w, "<": value < w}[op]


def _get(node, dotted: str):
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


_JSON_CACHE: dict[Path, object] = {}


def load_json(path: Path):
    if path not in _JSON_CACHE:
        try:
            _JSON_CACHE[path] = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise FigureError(f"cannot read {path}: {e}") from None
    return _JSON_CACHE[path]


def _short_run() -> bool:
    """Whether the data comes from the documentation's commands run short (console.docs_quick): there a
    short-trained policy may crash every episode, and a figure that selects only blanks prints "–"."""
    from quadpilot.console import docs_quick

    return docs_quick()


def resolve(ref: str, sources: dict[str, str], root: Path = ROOT) -> str:
    """The text a mark's reference must print: the JSON value, reduced, scaled and formatted."""
    head, _, fmt = ref.rpartition(" ")
    source, sep, path = head.strip().partition("#")
    if not sep or not fmt:
        raise FigureError(f"expected `SOURCE#PATH FORMAT` in the mark, got {ref!r}")
    file = root / sources.get(source, source)
    m = FORMAT_RE.match(fmt)
    if m is None:
        raise FigureError(f"format {fmt!r}: expected [mean|min|max|sum|len|pNN][*N|/N]:SPEC")
    value = _walk(load_json(file), path, f"{file.relative_to(root)}#{path}")
    if isinstance(value, list):
        if not m.group("reduce"):
            raise FigureError(f"{ref!r}: the path selects {len(value)} values; add a reduction (mean, min, ...)")
        red = m.group("reduce")
        if red != "len":  # blank cells (None) are not values; `len` counts what the path selected
            value = [v for v in value if v is not None]
            if not value and _short_run():
                return "–"
            if not value:
                raise FigureError(f"{ref!r}: the path selects no value to reduce")
        value = _percentile(value, int(red[1:])) if red.startswith("p") else REDUCERS[red](value)
    elif m.group("reduce"):
        raise FigureError(f"{ref!r}: a reduction needs a `*` in the path")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FigureError(f"{ref!r}: the value is {value!r}, not a number")
    if m.group("op"):
        scale = float(m.group("scale"))
        value = value * scale if m.group("op") == "*" else value / scale
    try:
        return format(value, m.group("spec"))
    except ValueError as e:
        raise FigureError(f"{ref!r}: {e}") from None


def _same(printed: str, expected: str) -> bool:
    return printed.replace("−", "-") == expected


# ---------------------------------------------------------------------------------------------
# Generated blocks

BLOCK_RE = re.compile(r"<!-- BEGIN generated: (?P<cmd>[^\n]*?) -->\n(?P<body>.*?)<!-- END generated -->", re.S)


@dataclass(frozen=True)
class Block:
    doc: Path
    line: int
    cmd: str
    body: str
    start: int  # offset of the body
    end: int


def blocks(doc: Path, text: str | None = None) -> list[Block]:
    text = doc.read_text() if text is None else text
    return [
        Block(doc, text.count("\n", 0, m.start()) + 1, m.group("cmd"), m.group("body"), m.start("body"), m.end("body"))
        for m in BLOCK_RE.finditer(text)
    ]


_OUTPUT_CACHE: dict[str, str] = {}


def run_report(cmd: str, root: Path = ROOT) -> str:
    """Standard output of `python SCRIPT ARGS...`, run in this process from the repository root
    (report scripts read JSON and print Markdown; nothing is written)."""
    if cmd not in _OUTPUT_CACHE:
        argv = shlex.split(cmd)
        if not argv or not argv[0].endswith(".py") or "--strip-data" in argv:
            raise FigureError(f"generated block: expected `SCRIPT.py ARGS` of a report script, got {cmd!r}")
        out, old_argv, old_cwd = io.StringIO(), sys.argv, Path.cwd()
        try:
            sys.argv = [str(root / argv[0]), *argv[1:]]
            import os

            os.chdir(root)
            with contextlib.redirect_stdout(out):
                try:
                    runpy.run_path(str(root / argv[0]), run_name="__main__")
                except SystemExit as e:
                    if e.code not in (None, 0):
                        raise FigureError(f"generated block: `{cmd}` exited with {e.code}") from None
        finally:
            sys.argv = old_argv
            os.chdir(old_cwd)
        _OUTPUT_CACHE[cmd] = out.getvalue()
    return _OUTPUT_CACHE[cmd]


def _block_text(s: str) -> str:
    return s.strip("\n") + "\n"


# ---------------------------------------------------------------------------------------------
# Unmarked figures in prose

# A unit after a number that makes it a measurement, unless allowed below. Longest first.
UNITS = (
    r"(?:[\w-]+ )?steps/s",
    r"(?:control |drone-|vector |gradient |environment |training )?steps\b",
    r"cm/s",
    r"m/s",
    r"%",
    r"×(?!\s?\d)",
    r"x\b",
    r"cm\b",
    r"mm\b",
    r"m\b",
    r"µs\b",
    r"us\b",
    r"ms\b",
    r"ns\b",
    r"s\b",
    r"min\b",
    r"minutes\b",
    r"seconds\b",
    r"hours?\b",
    r"MHz\b",
    r"Hz\b",
    r"KB\b",
    r"KiB\b",
    r"MB\b",
    r"B\b",
    r"cycles\b",
    r"°",
    r"M\b",
    r"k\b",
)
_NUM = r"(?<![\w.\-/#@×])[-−+±]?\d+(?:[,\u202f]\d{3})*(?:\.\d+)?(?![\d.]?\w)"
_ITEM = rf"(?:{_NUM}|\uE000)"  # \uE000 stands for a marked figure
_SEP = r"\s?(?:[–/→]|-(?=\d)|…|to|and|or|,)\s?"
CANDIDATE_RE = re.compile(
    rf"(?P<group>{_ITEM}(?:{_SEP}{_ITEM})*)(?P<suffix>\s?[kM](?=\s))?\s?(?P<unit>{'|'.join(UNITS)})"
)
NUMBER_RE = re.compile(_NUM)

# Design constants: numbers with a unit that are parameters, definitions or limits chosen by the
# project (or by PX4, MAVLink, a data sheet), not results of a measurement. Each entry: a regular
# expression that must match a stretch of the prose containing the number, and why it is allowed.
ALLOWED: tuple[tuple[str, str], ...] = (
    (
        r"(?:[≤≥<>]|\b(?:above|below)\s)\s?\d[\d,.]*(?:\s?[kM])?\s?(?:×|%|cm/s|m/s|cm|mm|m|µs|ms|s|°|drone-steps)",
        "a bound after ≤, ≥, <, >, above or below is a target, tolerance or limit the text states, not a result",
    ),
    (
        r"±\d[\d.]*(?:\s?[–-]\s?\d[\d.]*)?\s?(?:%|m/s|m|°)",
        "±N is a range a parameter is drawn from or checked against (start states, randomisation, the grid, "
        "wire limits)",
    ),
    (
        r"\d+(?:\s+and\s+\d+)?\s?M?Hz",
        "rates and clocks are configuration: the control loop (EnvConfig.dt), PX4/MAVLink message rates, the "
        "STM32F4's clock",
    ),
    (r"\bup\s+to\s+500\s+µs", "the lockstep spin window (link.spin.LOCKSTEP_SPIN_S, --spin-us)"),
    (
        r"\b0[–-]50\s?ms|±\s?10\s?ms|\b20\s?ms\s+each\s+way|\bup\s+to\s+60\s?ms",
        "quad-train's default timing (core.timing preset link: delays of 0-50 ms each way, ±10 ms of jitter, "
        "so up to 60 ms) and the fixed link a policy trained through it is judged at (20 ms each way, "
        "train.runs.loop.JUDGED_TIMINGS)",
    ),
    (r"\b95\s+%", "the success bar: 95 % of 100 evaluation episodes (train.runs.loop.SUCCESS_BAR)"),
    (
        r"last\s+2\s+s|\b5\s+s\s+episode|episodes\s+of\s+5\s+s|\b5\s+cm\b(?!/)",
        "the hover success definition (core.mission): mean error over the last 2 s of a 5 s episode within 5 cm",
    ),
    (r"\b[123]\s+M\b(?:\s+steps|-step)?", "training budgets (--total-steps; 1 M is the default)"),
    (
        r"0\.5\s+→\s+1\s+→\s+2\s+m|within\s+1\s+m\b|\b1\s+m\s+circle\s+at\s+1\s+m/s|σ\s+0?\.?\d+\s+m|\b1\s+m\s+offset|"
        r"rest\s+1\s+m\s+from|\b2\s+m\s+targets",
        "task definitions: the start radius, the curriculum's radii, the ENPM 667 circle, the reward's Gaussian "
        "widths, the offset scenario, waypoint targets",
    ),
    (
        r"\b60°|\b5\s+m\b|\b40°|\(0°,\s+90°\)",
        "crash and safety envelopes and the tilt penalty's threshold (core.reward, runtime.safety, modelfile.model)",
    ),
    (
        r"\b(?:30|60)\s+ms\b|\b0–30\s+ms|\b30–60\s+ms",
        "motor time constants set by --motor-tau or the randomisation preset",
    ),
    (r"\b500\s+steps|\b0\.01\s+s\b", "the episode: 500 steps of 0.01 s (EnvConfig)"),
    (
        r"headings\s+within\s+30°|\b4\s+m\s+by\s+2\s+m|ramped\s+up\s+over\s+3\s+s|\b1,\s+2\s+and\s+4\s+m/s|"
        r"\b1\s+and\s+2\s+m/s|\bat\s+[124]\s+m/s|the\s+5\s+s\s+ended|within\s+its\s+10\s+ms|"
        r"hit\s+3\s+s\s+into\s+a\s+7\s+s\s+hover|hover\s+to\s+0\.95\s+m|motor\s+lag\s+of\s+0\s+to\s+150\s+ms",
        "the airframe comparison's flights (core.maneuver, benchmarks/airframes.py): commanded headings, the "
        "figure-eight's size, ramp and speeds, the step's duration, RotorPy's wait for an answer, the impulse "
        "flight, RotorPy's hover target, the generalist's drawn motor lag (core.randomization)",
    ),
    (
        r"\b10×|\b50×\s+the\s+default|\b10×\s+the\s+default|20×\s+larger\s+rewards\s+give\s+400×|~14×",
        "ratios that are not results: the issue's 10× target, learning rates as multiples of the default, "
        "the arithmetic of squared errors, the design notes' claim the paragraph refutes",
    ),
    (
        r"\b[012]\s+m/s\b|(?:0–)?1\.5\s+m/s|0\s+→\s+2\s+m/s|0\.30\s+m/s\s+imparted|0\s+and\s+1\s+m/s",
        "wind speeds and pushes of the grid, the disturbance scenarios and the randomisation preset",
    ),
    (
        r"0\.1–0\.3\s+s|\b0\.2\s+s|t\s+=\s+1\s+s|\b8\s+s\s+flights",
        "timing of the disturbance scenarios and pushes (studies.robustness, core.randomization)",
    ),
    (
        r"\b(?:15|8)\s+%\s+(?:heavier|weaker)|deficit\s+of\s+25\s+%",
        "the grid's plants: mass ×1.15, k_f ×0.92 (studies.robustness.GRID_*)",
    ),
    (
        r"1\s+cm\s+(?:\+|position|quantis)|1\.1\s+cm\s+latitude,\s+0\.75\s+cm\s+longitude,\s+1\s+mm\s+altitude,\s+1\s+cm/s|"
        r"within\s+1\s+cm\s+of|\b2\s+cm\s+bound|1\s+±\s+1\s+%|1\s+%\s+from\s+unit",
        "the wire's quantisation (MAVLink's integer units), a data sheet's accuracy, settling and test tolerances",
    ),
    (
        r"\d[\d,.]*(?:\s+and\s+[\d.]+)?\s+gradient\s+steps|\b(?:64|128)\s+steps|(?:8,192|81,920)\s+steps|"
        r"rounds\s+of\s+50\s+steps|every\s+10\s+environment\s+steps|100,000\s+steps|300\s+k\s+steps|"
        r"2,000\s+control\s+steps|\b20\s+s\s+episode|one\s+5\s+s\s+flight|first\s+0\.2\s+s",
        "sizes of runs, rollouts, updates, evaluation intervals and benchmarks, fixed by their configuration",
    ),
    (r"32\s+KiB", "arithmetic: one float64 row of 4,096 drones"),
    (
        r"within\s+10°\s+of|same\s+2\s+s|over\s+its\s+last\s+2\s+s|last\s+2\s+s|\s+2\s+s:\s+error|(?:larger\s+than|most|runs)\s+25°|"
        r"within\s+30°\s+of|a\s+90°\s+and\s+a\s+180°\s+turn",
        "the yaw rule (core.mission: heading within 10° over the last 2 s), the training's commanded-heading offset "
        "(30°, EnvConfig.heading_offset_deg), the node's heading reach (25°, autopilot.node.HEADING_REACH_RAD) and "
        "the turns a test commands",
    ),
    (
        r"about\s+1\s+m\s+away|0\.95\s+m;|0\.91\s+m\)|bound\s+for\s+it\s+is\s+10\s+cm",
        "the RotorPy test's targets (the length of its --target offsets) and its bound for a policy flown on "
        "another vehicle (tests/sitl/test_rotorpy.py)",
    ),
    (
        r"\b1[05]0\s+ms\b",
        "the link-loss and ESC timeouts (100 ms; PX4's COM_DL_LOSS_T plays this role) and the fault tests' bound",
    ),
    (
        r"2\.5\s+m\s+and\s+30°",
        "the safety monitor's recovery envelope: RECOVERY_FRACTION of the hover file's 5 m and 60° (runtime.safety)",
    ),
    (
        r"(?:stalled|stopped)\s+for\s+2\s+s",
        "the stall the lockstep test imposes on the simulator (tests/sitl/test_handback_flights.py), a test setting",
    ),
    (
        r"\b10\s+ms\s+wait",
        "RotorPy's PX4Multirotor waits 10 ms for each answer (_fetch_latest_px4_control), a constant of that simulator",
    ),
)


@dataclass(frozen=True)
class Unmarked:
    doc: Path
    line: int
    text: str  # the number
    context: str  # the candidate with its unit

    def __str__(self) -> str:
        return f"{self.doc.name}:{self.line}: {self.context!r} ({self.text} is not marked)"


def _blank(text: str, spans, keep_newlines: bool = True) -> str:
    chars = list(text)
    for a, b in spans:
        for i in range(a, b):
            if not keep_newlines or chars[i] != "\n":
                chars[i] = " "
    return "".join(chars)


CONSTANTS_RE = re.compile(r"<!-- BEGIN constants:(?P<why>[^\n]*?)-->\n.*?<!-- END constants -->", re.S)


def prose(text: str) -> str:
    """`text` with everything that is not prose blanked (same length, same line breaks); each marked
    figure becomes one \\uE000 followed by blanks, so a range of marked figures is still a range."""
    spans = [(b.start, b.end) for b in blocks(Path("-"), text)]
    spans += [m.span() for m in CONSTANTS_RE.finditer(text)]
    out = _blank(text, spans)
    chars = list(out)
    for m in MARK_RE.finditer(text):
        chars[m.start()] = "\ue000"
        for i in range(m.start() + 1, m.end()):
            chars[i] = " "
    out = "".join(chars)
    spans = []
    # fenced code: keep only `#` comments of each line
    for m in re.finditer(r"^(```|~~~).*?^\1[ \t]*$", out, re.S | re.M):
        body = m.group(0)
        pos = m.start()
        for line in body.splitlines(keepends=True):
            hash_at = line.find(" # ")
            if hash_at < 0 and line.lstrip().startswith("#") and not line.startswith("```"):
                hash_at = line.find("#")
            spans.append((pos, pos + (len(line) if hash_at < 0 else hash_at)))
            pos += len(line)
    out = _blank(out, spans)
    spans = [m.span() for m in re.finditer(r"<!--.*?-->", out, re.S)]
    spans += [m.span() for m in re.finditer(r"`[^`\n]*`", out)]
    spans += [m.span() for m in re.finditer(r"\$\$.*?\$\$|\$[^$\n]+\$", out, re.S)]
    spans += [m.span(1) for m in re.finditer(r"\]\(([^)\s]*)\)", out)]
    spans += [m.span() for m in re.finditer(r"<[a-zA-Z/][^>\n]*>", out)]
    return _blank(out, spans)


def unmarked(doc: Path, text: str | None = None, allowed=None) -> list[Unmarked]:
    text = doc.read_text() if text is None else text
    allowed = ALLOWED if allowed is None else allowed
    clean = prose(text)
    # each allowed stretch, blanked: its numbers are constants
    spans = [m.span() for pattern, _ in allowed for m in re.finditer(pattern, clean)]
    covered = set()
    for a, b in spans:
        covered.update(range(a, b))
    found = []
    for m in CANDIDATE_RE.finditer(clean):
        for n in NUMBER_RE.finditer(m.group("group")):
            at = m.start("group") + n.start()
            if at in covered:
                continue
            line = clean.count("\n", 0, at) + 1
            found.append(Unmarked(doc, line, n.group(0), m.group(0).replace("\ue000", "#")))
    return found


# ---------------------------------------------------------------------------------------------
# Checking and updating


def _name(doc: Path, root: Path) -> str:
    return str(doc.relative_to(root)) if doc.is_relative_to(root) else str(doc)


def check_marks(doc: Path, root: Path = ROOT, text: str | None = None) -> list[str]:
    """A marked figure that differs from its JSON, or a mark that cannot be resolved."""
    text = doc.read_text() if text is None else text
    name, problems = _name(doc, root), []
    try:
        sources = aliases(text)
    except FigureError as e:
        return [f"{name}: {e}"]
    found = marks(doc, text)
    for mk in found:
        try:
            want = resolve(mk.ref, sources, root)
        except FigureError as e:
            problems.append(f"{name}:{mk.line}: {e}")
            continue
        if not _same(mk.text, want):
            problems.append(f"{name}:{mk.line}: printed {mk.text}, the JSON says {want} ({mk.ref})")
    # a `<!--=` that is not a mark right after a number would otherwise hide a figure unchecked
    starts = {text.index("<!--=", mk.end) for mk in found}
    code = _in_code(text)
    for m in re.finditer(r"<!--=", text):
        if m.start() not in starts and not any(a <= m.start() < b for a, b in code):
            line = text.count("\n", 0, m.start()) + 1
            problems.append(
                f"{name}:{line}: a mark must follow the number it marks, on one line: `N<!--= SRC#PATH FMT-->`"
            )
    return problems


def check_blocks(doc: Path, root: Path = ROOT, text: str | None = None) -> list[str]:
    """A generated block that differs from its report script's output; a constants block without a
    reason."""
    text = doc.read_text() if text is None else text
    name, problems = _name(doc, root), []
    for b in blocks(doc, text):
        try:
            want = _block_text(run_report(b.cmd, root))
        except FigureError as e:
            problems.append(f"{name}:{b.line}: {e}")
            continue
        if _block_text(b.body) != want:
            diff = [
                f"    doc: {x!r}\n    now: {y!r}"
                for x, y in zip(_block_text(b.body).splitlines(), want.splitlines(), strict=False)
                if x != y
            ][:3]
            problems.append(
                f"{name}:{b.line}: generated block differs from `{b.cmd}`" + ("\n" + "\n".join(diff) if diff else "")
            )
    for m in CONSTANTS_RE.finditer(text):
        if len(m.group("why").strip()) < 10:
            line = text.count("\n", 0, m.start()) + 1
            problems.append(f"{name}:{line}: a constants block must say why its values are not measurements")
    return problems


def check_prose(doc: Path, root: Path = ROOT, text: str | None = None) -> list[str]:
    """A number with a unit of measurement in prose that is neither marked nor allowed."""
    return [str(u) for u in unmarked(doc, text)]


def check(docs: list[Path] | None = None, root: Path = ROOT) -> list[str]:
    """Every problem of the three kinds, over README.md, docs/*.md and models/README.md (or `docs`)."""
    problems = []
    for doc in documents(root) if docs is None else docs:
        text = doc.read_text()
        problems += check_marks(doc, root, text) + check_blocks(doc, root, text) + check_prose(doc, root, text)
    return problems


def update(docs: list[Path] | None = None, root: Path = ROOT) -> tuple[int, list[str]]:
    """Rewrite every marked figure and generated block from the JSON. Returns how many changed and
    the marks or blocks that could not be resolved (left as they are)."""
    changed, errors = 0, []
    for doc in documents(root) if docs is None else docs:
        text = doc.read_text()
        sources = aliases(text)
        edits = []
        for mk in marks(doc, text):
            try:
                want = resolve(mk.ref, sources, root)
            except FigureError as e:
                errors.append(f"{doc.name}:{mk.line}: {e}")
                continue
            if not _same(mk.text, want):
                edits.append((mk.start, mk.end, want.replace("-", "−") if "−" in mk.text else want))
        for b in blocks(doc, text):
            try:
                want = _block_text(run_report(b.cmd, root))
            except FigureError as e:
                errors.append(f"{doc.name}:{b.line}: {e}")
                continue
            if _block_text(b.body) != want:
                edits.append((b.start, b.end, want))
        for a, b, new in sorted(edits, reverse=True):
            text = text[:a] + new + text[b:]
        if edits:
            doc.write_text(text)
            changed += len(edits)
    return changed, errors


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in ("check", "update", "unmarked"):
        print("usage: docs/figures.py check | update | unmarked FILE.md", file=sys.stderr)
        return 2
    if argv[0] == "unmarked":
        for f in argv[1:]:
            for u in unmarked(Path(f).resolve()):
                print(u)
        return 0
    if argv[0] == "update":
        n, errors = update()
        for e in errors:
            print(e)
        print(f"{n} figure(s) or block(s) rewritten; {len(errors)} could not be resolved")
        return 1 if errors else 0
    problems = check()
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
