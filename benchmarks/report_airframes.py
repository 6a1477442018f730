"""The table of docs/raptor.md from benchmarks/airframes.py's JSON:

    python benchmarks/report_airframes.py docs/bench/airframes.json

One row per airframe and controller, one column per flight: success (of the episodes) and the mean
error over the last 2 s (of the episodes that did not crash), or why quad-sitl refused to fly."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def cell(r: dict) -> str:
    if "refused" in r:
        return "refused"
    err = r.get("mean_error_last_2s_m")
    err_s = "–" if err is None or err != err else f"{100 * err:.1f} cm"
    crash = f", {r['crashes']} crashed" if r.get("crashes") else ""
    return f"{100 * r['success_rate']:.0f} % · {err_s}{crash}"


def table(data: dict) -> str:
    flights = list(data["flights"])
    lines = ["| airframe | controller | " + " | ".join(flights) + " |", "|---|---|" + "---|" * len(flights)]
    for name, rows in data["airframes"].items():
        for controller in ("raptor", "ours"):
            if controller in rows:
                lines.append(
                    f"| {name} | {controller} | " + " | ".join(cell(rows[controller][f]) for f in flights) + " |"
                )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    data = json.loads(Path(argv[0]).read_text())
    print(table(data))
    runs = [rows.get("run", data) for rows in data["airframes"].values()]
    commits = ", ".join(sorted({r["commit"][:10] for r in runs}))
    loads = [r["load_1min_before"] for r in runs]
    print(
        f"\n{data['episodes']} episodes per cell (success · mean error over the last 2 s); "
        f"{data['machine']['cpus']} CPUs, load {min(loads):.1f} to {max(loads):.1f} at the starts; "
        f"commit {commits}."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
