"""Markdown table of benchmarks/delay_grid.py's result: hover policies flown in-process through fixed
delays (docs/robustness.md quotes it, generated).

    .venv/bin/python benchmarks/report_delay_grid.py docs/bench/delay_grid.json

One row per (delay each way, jitter) cell, one column per policy: hover success (the project's rule),
crashes, and the mean hover error over the last 2 s of the episodes, in cm.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def cell(c: dict) -> str:
    err = c["mean_error_last_window_m"]
    error = "–" if err is None else f"{err * 100:.2f} cm"
    return f"{c['success_rate']:.0%} · {c['crash_rate']:.0%} · {error}"


def table(doc: dict) -> list[str]:
    names = list(doc["policies"])
    out = [
        "| delay each way ± jitter | " + " | ".join(f"`{n}`" for n in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    cells = [doc["policies"][n]["cells"] for n in names]
    for row in zip(*cells, strict=True):
        first = row[0]
        out.append(
            f"| {first['delay_ms']:g} ms ± {first['jitter_ms']:g} ms | " + " | ".join(cell(c) for c in row) + " |"
        )
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    args = p.parse_args(argv)
    try:
        doc = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"report_delay_grid: cannot read {args.json}: {e}", file=sys.stderr)
        return 2
    print("\n".join(table(doc)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
