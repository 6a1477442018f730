"""Markdown table of the state-loss flights (docs/robustness.md quotes it, generated).

    .venv/bin/python benchmarks/report_state_loss.py docs/bench/state_loss.json [docs/bench/state_loss_rotorpy.json]

One row per simulator, condition and rate: the episodes that met the hover rule (with the Wilson
95 % interval of that share), crashes, landings (the node said landed), the fastest touchdown, the
largest tilt before it, the fastest descent anywhere in the flight, steps flown with every motor off
in the air, and how the node ended the flights. A file may hold its simulator's name (`simulator`);
without one it is ours.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a share k/n (95 % for z = 1.96)."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def _max(rows, key: str, fmt: str) -> str:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return format(max(vals), fmt) if vals else "–"


def table(files: list[Path]) -> str:
    lines = [
        "| simulator | condition | rate (Hz) | hover rule met (95 % interval) | crashes | landed | "
        "touchdown, fastest (m/s) | tilt before it, largest (°) | fastest descent (m/s) | "
        "steps with motors off in the air | how the node ended them |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for path in files:
        data = json.loads(path.read_text())
        sim = data.get("simulator", "ours")
        for cell in data["cells"]:
            rows = cell["episodes"]
            n = len(rows)
            k = sum(r["hover_rule"] for r in rows)
            lo, hi = wilson(k, n)
            ends = Counter(r["failsafe"] or "flew on" for r in rows)
            lines.append(
                f"| {sim} | {cell['condition']} | {cell['rate_hz']} | {k}/{n} ({lo:.0%}–{hi:.0%}) | "
                f"{sum(r['crashed'] for r in rows)} | {sum('landed' in r['phases'] for r in rows)} | "
                f"{_max(rows, 'touchdown_speed_mps', '.2f')} | {_max(rows, 'touchdown_tilt_deg', '.1f')} | "
                f"{_max(rows, 'max_descent_speed_mps', '.2f')} | "
                f"{sum(r['motors_off_airborne_steps'] for r in rows)} | "
                + "; ".join(f"{why} ({c})" for why, c in ends.most_common())
                + " |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path, nargs="+", help="benchmarks/state_loss.py's result (and RotorPy's)")
    args = p.parse_args(argv)
    print(table(args.json))
    return 0


if __name__ == "__main__":
    sys.exit(main())
