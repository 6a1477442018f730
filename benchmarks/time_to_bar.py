"""Time to the hover bar, today's code against the baseline commit, side by side in one run.

    .venv/bin/python benchmarks/time_to_bar.py --seeds 0 1 2 --out docs/bench/time_to_bar.json

For each seed it runs `quad-train --task hover --seed N --out DIR` twice, once with the baseline
commit's source (benchmarks/baseline.py) and once with today's, alternating so that a change in the
machine's load falls on both, and reads each run's eval.json: `first_success.train_time_s` is the
training wall-clock (periodic evaluations excluded) until the first periodic evaluation whose
success rate reached 95 %. Each version is judged by its own success rule: the baseline's hover bar
is position only, today's also asks the heading to be held (core.mission.window_success), so today's
code has to reach a stricter bar. The JSON holds every run's figures, the medians over seeds and
their ratio (baseline ÷ today: 2 means twice as fast to the bar).

`--total-steps` shortens the runs: a smoke test of the script, not a measurement (the learning-rate
anneal follows the total, so the figures differ from the default command's).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from baseline import BASELINE_COMMIT, REPO, baseline_src, run_python
from quadpilot.train.runs.loop import machine

TRAIN = "import sys; from quadpilot.train.cli import main; sys.exit(main(sys.argv[1:]))"


def _one(src: Path | None, seed: int, out: Path, total_steps: int | None) -> dict:
    args = ["--task", "hover", "--seed", str(seed), "--out", str(out)]
    if total_steps:
        args += ["--total-steps", str(total_steps)]
    t0 = time.perf_counter()
    run_python(TRAIN, src, *args)
    wall = time.perf_counter() - t0
    e = json.loads((out / "eval.json").read_text())
    fs = e.get("first_success")
    return {
        "seed": seed,
        "reached": fs is not None,
        "first_success_step": fs["global_step"] if fs else None,
        "first_success_train_time_s": fs["train_time_s"] if fs else None,
        "final_success_rate": e["success_rate"],
        "global_step": e["global_step"],
        "train_time_s": e["train_time_s"],
        "wall_s": wall,
    }


def _median(runs: list[dict]) -> float | None:
    t = [r["first_success_train_time_s"] for r in runs]
    return statistics.median(t) if t and None not in t else None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--out", type=Path, required=True, help="JSON file to write")
    p.add_argument("--baseline", default=BASELINE_COMMIT, help="commit to compare with (default %(default)s)")
    p.add_argument("--total-steps", type=int, default=None, help="shorter runs, for a smoke test only")
    p.add_argument("--work", type=Path, default=None, help="where the run directories go (default: a temp dir)")
    args = p.parse_args(argv)
    src = baseline_src(args.baseline)
    work = args.work or Path(tempfile.mkdtemp(prefix="time_to_bar-"))
    runs: dict[str, list[dict]] = {"baseline": [], "today": []}
    for seed in args.seeds:
        for name, s in (("baseline", src), ("today", None)):
            r = _one(s, seed, work / f"{name}-seed{seed}", args.total_steps)
            runs[name].append(r)
            t = r["first_success_train_time_s"]
            print(
                f"{name:<8} seed {seed}: "
                + (f"bar at {r['first_success_step']:,} steps, {t:.1f} s of training" if t else "bar not reached")
                + f" (run {r['wall_s']:.0f} s wall)",
                flush=True,
            )
    med = {k: _median(v) for k, v in runs.items()}
    ratio = med["baseline"] / med["today"] if med["baseline"] and med["today"] else None
    result = {
        "command": "python benchmarks/time_to_bar.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "baseline_commit": args.baseline,
        "today_commit": _git_head(),
        "machine": {**machine(), "cores": os.cpu_count(), "python": platform.python_version()},
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "total_steps": args.total_steps,
        "runs": runs,
        "median_first_success_train_time_s": med,
        "every_seed_reached": {k: all(r["reached"] for r in v) for k, v in runs.items()},
        "speedup_median": ratio,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(
        f"median time to the bar: baseline {med['baseline']} s, today {med['today']} s; "
        + (f"today is {ratio:.2f}x faster" if ratio else "no ratio (a version did not reach the bar)")
    )
    return 0


def _git_head() -> str:
    import subprocess

    try:
        git = ["git", "-C", str(REPO)]
        head = subprocess.run([*git, "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True, check=True)
        dirty = subprocess.run([*git, "status", "--porcelain", "src"], capture_output=True, text=True, check=True)
        return head.stdout.strip() + ("+uncommitted changes in src" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


if __name__ == "__main__":
    raise SystemExit(main())
