"""Markdown table of benchmarks/soak.py's results (docs/benchmarks.md quotes it, generated).

    .venv/bin/python benchmarks/report_soak.py docs/bench/soak_lockstep.json [docs/bench/soak_realtime.json ...]

One row per soak: steps and wall time, RSS growth of the node (as read, and after malloc_trim) and of
the simulator from the first episode to the last, lost steps, failsafes, packets dropped by either
side, the simulator's real-time overruns, and the node's step-time percentiles. Goals: RSS growth
≤ 2 MiB per process, zero lost steps.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _mib(v) -> str:
    return "–" if v is None else f"{v:+.2f}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path, nargs="+")
    args = p.parse_args(argv)
    print(
        "| soak | steps | wall (s) | node RSS growth, as read / trimmed (MiB) | simulator RSS growth (MiB) "
        "| lost steps "
        "| failsafes | dropped (node, simulator) | overruns | step time p50 / p99 / p99.9 / max (ms) | machine |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for path in args.json:
        try:
            d = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            print(f"report_soak: cannot read {path}: {e}", file=sys.stderr)
            return 2
        t = d["step_time_ms"]
        m = d["machine"]
        print(
            f"| {d['mode']}, {d['rate_hz']} Hz, {len(d['episodes'])} episodes | {d['steps']:,} | {d['wall_s']:,.0f} | "
            f"{_mib(d['node_rss_growth_mib'])} / {_mib(d.get('node_rss_trimmed_growth_mib'))} | "
            f"{_mib(d['sim_rss_growth_mib'])} | {d['lost_steps']} | {d['failsafes']} | "
            f"{d['node_dropped']}, {d['sim_dropped']} | {d['sim_overruns']} | "
            f"{t['p50']:.2f} / {t['p99']:.2f} / {t['p99.9']:.2f} / {t['max']:.1f} | "
            f"{m['cpu']}, {m['cores']} cores, {d['date'][:10]}; {d['note']} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
