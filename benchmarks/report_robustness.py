"""Markdown tables of docs/robustness.md from the robustness study's JSON, drawn by the study's own
table functions (`quadpilot.studies.robustness.grid_table`, `scenario_table`).

    .venv/bin/python benchmarks/report_robustness.py docs/bench/robustness/robustness.json --table grid

The JSON is written by `python -m quadpilot.studies.robustness ... --out docs/bench/robustness`
(docs/robustness.md gives the whole command): `grid` (in-process, 100 episodes per cell), `sitl`
(quad-sitl, 10 episodes per cell) and `scenarios` (push, wind step, 1 m offset).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    p.add_argument("--table", choices=("grid", "sitl", "scenarios"), required=True)
    args = p.parse_args(argv)
    try:
        data = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"report_robustness: cannot read {args.json}: {e}", file=sys.stderr)
        return 1
    from quadpilot.studies.robustness import grid_table, scenario_table

    if args.table == "scenarios":
        print(scenario_table(data["scenarios"]))
    else:
        print(grid_table(data[args.table]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
