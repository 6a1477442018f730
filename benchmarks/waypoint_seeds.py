"""The README's waypoint command over several seeds: does every seed end at the waypoint bar?

    .venv/bin/python benchmarks/waypoint_seeds.py --seeds 0 1 2 3 4 --out docs/bench/waypoint_seeds.json

For each seed it runs `quad-train --task waypoint --total-steps 2000000 --seed N --out DIR` (today's
defaults, the curriculum to 2 m) and keeps from its eval.json what the final policy did over the
100 evaluation episodes: success (position within 5 cm and heading held, core.mission), the worst
episode's mean heading error and mean position error over the judged window, crashes, and where
training first reached the 95 % bar. `--total-steps` shortens the runs for a smoke test (the
learning-rate anneal follows the total, so the figures are not the command's).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from quadpilot.console import quick
from quadpilot.train.cli import main as train
from quadpilot.train.runs.loop import machine

TOTAL_STEPS = 2_000_000


def _one(seed: int, out: Path, total_steps: int) -> dict:
    argv = ["--task", "waypoint", "--total-steps", str(total_steps), "--seed", str(seed), "--out", str(out)]
    t0 = time.perf_counter()
    code = train(argv)
    if code != 0:
        raise SystemExit(f"waypoint_seeds: quad-train {' '.join(argv)} exited {code}")
    e = json.loads((out / "eval.json").read_text())
    first = e.get("first_success") or {}
    return {
        "seed": seed,
        "success_rate": e["success_rate"],
        "crash_rate": e["crash_rate"],
        "worst_heading_error_deg": e["max_mean_heading_error_last_window_deg"],
        "mean_error_last_window_m": e["mean_error_last_window_m"],
        "max_error_last_window_m": e["max_error_last_window_m"],
        "first_success_step": first.get("global_step"),
        "global_step": e["global_step"],
        "wall_s": time.perf_counter() - t0,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--total-steps", type=int, default=TOTAL_STEPS)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    args.seeds = args.seeds[: quick(len(args.seeds), 2)]  # QUADPILOT_DOCS_QUICK: two seeds (quad-train's steps cap too)
    runs = []
    with tempfile.TemporaryDirectory(prefix="waypoint-seeds-") as tmp:
        for seed in args.seeds:
            runs.append(_one(seed, Path(tmp) / f"seed{seed}", args.total_steps))
            r = runs[-1]
            head = r["worst_heading_error_deg"]  # None when every episode crashed
            head = "none flew the window" if head is None else f"{head:.1f}°"
            print(
                f"seed {seed}: success {r['success_rate']:.0%}, worst heading {head}, bar first at "
                f"{r['first_success_step']}",
                flush=True,
            )
    doc = {
        "command": " ".join(["python", "benchmarks/waypoint_seeds.py", *(argv if argv is not None else sys.argv[1:])]),
        "train_command": f"quad-train --task waypoint --total-steps {args.total_steps} --seed N --out DIR",
        "machine": machine(),
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "runs": runs,
        "seeds_at_bar": sum(r["success_rate"] >= 0.95 for r in runs),
        "worst_heading_error_deg": max((r["worst_heading_error_deg"] or 0.0 for r in runs), default=None),
    }
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
