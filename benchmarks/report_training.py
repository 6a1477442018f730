"""Markdown table of training runs from the files quad-train wrote: `config.json` (the command, seed,
threads) and `eval.json` (the final evaluation, the first periodic evaluation at ≥ 95 % success, the
training time and where it went).

    .venv/bin/python benchmarks/report_training.py models/hover models/waypoint models/circle

quad-train measures everything here itself: `train_time_s` is training wall-clock with the periodic
evaluations excluded, `first_success` the first evaluation (100 deterministic episodes every 10
updates) whose success rate reached 95 %, `time_breakdown_s.fractions` the environment / policy
inference and rollout bookkeeping / update split summed from metrics.csv.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _final(e: dict) -> str:
    if "radial_rms_m" in e:
        return (
            f"success {100 * e['circle_success_rate']:.0f} %, radial RMS {100 * e['radial_rms_m']:.2f} cm, "
            f"speed error {100 * e['speed_error_mps']:.2f} cm/s"
        )
    if e.get("task") == "waypoint":
        return f"success {100 * e['success_rate']:.0f} %, final distance {100 * e['mean_final_distance_m']:.1f} cm"
    return f"success {100 * e['success_rate']:.0f} %, mean error {100 * e['mean_error_last_window_m']:.1f} cm"


def row(run: Path) -> str:
    try:
        e = json.loads((run / "eval.json").read_text())
        c = json.loads((run / "config.json").read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise SystemExit(f"report_training: {run}: {err}") from None
    fs = e.get("first_success")
    first = f"{fs['global_step']:,} | {fs['train_time_s']:.1f}" if fs else "not reached | –"
    f = e["time_breakdown_s"]["fractions"]
    split = f"{100 * f['env_s']:.0f} % / {100 * f['inference_s']:.0f} % / {100 * f['update_s']:.0f} %"
    return (
        f"| `{run.as_posix()}` | {c['task']} | {c['ppo']['seed']} | {c['ppo']['threads']} | {first} | {_final(e)} | "
        f"{e['global_step']:,} | {e['train_time_s']:.1f} | {e['global_step'] / e['train_time_s']:,.0f} | {split} |"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", type=Path, help="run directories (models/NAME or runs/NAME)")
    args = p.parse_args(argv)
    print(
        "| run | task | seed | torch threads | first eval ≥ 95 % at (steps) | training s to it | final eval "
        "(100 episodes) | steps | training s | steps/s | time: env / inference / update |"
    )
    print("|---|---|---:|---:|---:|---:|---|---:|---:|---:|---:|")
    for run in args.runs:
        print(row(run))
    return 0


if __name__ == "__main__":
    sys.exit(main())
