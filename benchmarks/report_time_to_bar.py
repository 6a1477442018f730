"""Markdown table of a time-to-the-hover-bar comparison written by benchmarks/time_to_bar.py.

.venv/bin/python benchmarks/report_time_to_bar.py docs/bench/time_to_bar.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _cell(r: dict) -> str:
    if not r["reached"]:
        return "not reached"
    return f"{r['first_success_step']:,} steps, {r['first_success_train_time_s']:.1f} s"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    args = p.parse_args(argv)
    try:
        d = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"report_time_to_bar: {args.json}: {e}", file=sys.stderr)
        return 1
    base, today = d["runs"]["baseline"], d["runs"]["today"]
    print(
        f"| seed | {d['baseline_commit']}: bar first at (its rule: position) | {d['today_commit'][:7]}: bar first at "
        "(its rule: position and heading) |"
    )
    print("|---:|---:|---:|")
    for b, t in zip(base, today, strict=True):
        print(f"| {b['seed']} | {_cell(b)} | {_cell(t)} |")
    med = d["median_first_success_train_time_s"]
    fmt = lambda v: "–" if v is None else f"{v:.1f} s"  # noqa: E731
    print(f"| median | {fmt(med['baseline'])} | {fmt(med['today'])} |")
    print()
    ratio = d["speedup_median"]
    reached = all(d["every_seed_reached"].values())
    verdict = "met" if ratio is not None and ratio >= 2.0 and reached else "NOT met"
    shown = "no ratio" if ratio is None else f"{ratio:.2f}×"
    print(f"- Target: median time to the bar ≤ half of the baseline's, every seed reaching it: {verdict} ({shown})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
