"""Markdown tables of benchmarks/link_faults.py's result: hover through an impaired link and through
sensor faults (docs/robustness.md quotes them, generated).

    .venv/bin/python benchmarks/report_link_faults.py docs/bench/link_faults.json [--table link|faults|targets]

Per condition and simulator rate: episodes that met the hover rule (`core.mission`), the error over
the last 2 s (mean over the episodes, and the worst episode's), episodes that crashed (the vehicle:
ground or tilt or flight area, `core.reward.crashed`), what the proxy did to the frames (lost
of relayed-or-lost, both directions), and what the node did: failsafes and why, episodes in which the
safety monitor's fallback flew, blind steps, and what it dropped.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


def _cm(v) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v * 100:.1f}"


def _did(r: dict) -> str:
    """What the node did in one row's flights, in words."""
    if "episodes" not in r:
        return f"no result: exit {r['exit_code']}"
    parts = []
    if r["failsafes"]:
        parts.append(f"failsafe in {r['failsafes']}/{r['episodes']} ({', '.join(r['failsafe_reasons'])})")
    if r["episodes_with_fallback"]:
        parts.append(f"fallback flew in {r['episodes_with_fallback']}/{r['episodes']}")
    if r.get("state_lost_steps"):
        parts.append(f"{r['state_lost_steps']:,} steps without a state flown on the node's estimate")
    blind = r["monitor_events"].get("blind_steps", 0)
    if blind:
        parts.append(f"{blind} blind steps")
    dropped = sorted(r["packets_dropped"].items(), key=lambda kv: -kv[1])[:2]
    if dropped:
        parts.append("dropped " + ", ".join(f"{k} {v:,}" for k, v in dropped))
    if r["crashed_process"]:
        parts.append(f"PROCESS FAILED (exit {r['exit_code']})")
    return "; ".join(parts) or "policy flew every step"


def _success(r: dict) -> str:
    return "–" if "episodes" not in r else f"{r['successes']}/{r['episodes']}"


def _lost(r: dict) -> str:
    li = r.get("link_impair")
    if li is None:
        return "–"
    frames = sum(li[d]["frames"] for d in ("up", "down"))
    lost = sum(li[d]["lost"] + li[d]["lost_burst"] for d in ("up", "down"))
    return f"{lost / frames:.1%} of {frames:,}" if frames else "0"


def _models(rows: list[dict]) -> list[str]:
    """The models the rows fly, in the order they first appear (rows made before --models: hover)."""
    return list(dict.fromkeys(r.get("model", "hover") for r in rows))


def table(rows: list[dict], kind: str) -> list[str]:
    head = "impairment (`--link-impair`)" if kind == "link" else "sensor fault (`--sensor-fault`)"
    lost = " frames lost |" if kind == "link" else ""
    several = len(_models(rows)) > 1
    out = [
        ("| policy " if several else "")
        + f"| {head} | Hz | hover success | crashed | error last 2 s, mean / worst (cm) |{lost} what the node did |",
        ("|---" if several else "") + "|---|---|---|---|---|" + ("---|" if kind == "link" else "") + "---|",
    ]
    for r in rows:
        if r["kind"] != kind:
            continue
        spec = f"`{r['spec']}`" if r["spec"] else "none"
        name = spec if r["condition"] == "none" else f"{r['condition']}: {spec}"
        cells = ([f"`{r.get('model', 'hover')}`"] if several else []) + [name, str(r["rate_hz"]), _success(r)]
        cells.append(str(r.get("crashes", "–")))
        cells.append(f"{_cm(r.get('mean_error_last_2s_m'))} / {_cm(r.get('max_error_last_2s_m'))}")
        if kind == "link":
            cells.append(_lost(r))
        cells.append(_did(r))
        out.append("| " + " | ".join(cells) + " |")
    return out


def targets(doc: dict) -> list[str]:
    out = ["| target | figure | met? |", "|---|---|---|"]
    rows = _sorted(doc["rows"])
    who = (lambda r: f"`{r.get('model', 'hover')}`, ") if len(_models(rows)) > 1 else (lambda r: "")
    for name, goal in doc["goals"].items():
        for r in (r for r in rows if r["condition"] == name):
            rate = r.get("success_rate")
            met = rate is not None and rate >= goal
            flown = "–" if rate is None else f"{rate:.0%} ({_success(r)})"
            verdict = "yes" if met else "no"
            out.append(f"| {who(r)}≥ {goal:.0%} hover success, {name}, {r['rate_hz']} Hz | {flown} | {verdict} |")
    for name in doc.get("no_crash", ()):
        for r in (r for r in rows if r["condition"] == name):
            crashes = r.get("crashes")
            flown = "–" if crashes is None else f"{crashes} of {r['episodes']} episodes crashed"
            verdict = "yes" if crashes == 0 else "no"
            out.append(f"| {who(r)}no crash, {name}, {r['rate_hz']} Hz | {flown} | {verdict} |")
    crashes = doc["process_crashes"]
    out.append(
        f"| the node never crashes (exit 0, or 1 after a failsafe; no traceback) | {crashes} of {len(doc['rows'])} "
        f"runs failed | {'yes' if crashes == 0 else 'no'} |"
    )
    return out


def _sorted(rows: list[dict]) -> list[dict]:
    """By model (in the order flown), kind and rate; within those, the order flown."""
    order = {m: i for i, m in enumerate(_models(rows))}
    return sorted(rows, key=lambda r: (order[r.get("model", "hover")], r["kind"], r["rate_hz"]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    p.add_argument("--table", choices=("link", "faults", "targets"), help="print only this table")
    args = p.parse_args(argv)
    try:
        doc = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"report_link_faults: cannot read {args.json}: {e}", file=sys.stderr)
        return 2
    rows = _sorted(doc["rows"])
    parts = {
        "link": table(rows, "link"),
        "faults": table(rows, "fault"),
        "targets": targets(doc),
    }
    if args.table is None:
        m = doc["machine"]
        print(f"Machine: {m['cpu']}, {m['cores']} cores, {doc['date']}; {doc['note']}\n")
    for name, lines in parts.items():
        if args.table in (None, name):
            print("\n".join(lines))
            if args.table is None:
                print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
