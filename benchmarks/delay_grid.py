"""Hover policies flown in-process through fixed delays: what training through delay bought.

    .venv/bin/python benchmarks/delay_grid.py --out docs/bench/delay_grid.json \\
        hover=models/hover/policy.pt hover_px4_sih=models/hover_px4_sih/policy.pt \\
        "hover before=OLD/hover.pt" "hover_px4_sih before=OLD/hover_px4_sih.pt"

Each policy flies `evaluate` (100 episodes, seed 2024, its own vehicle, start states and rule) with the
environment's timing (`core.timing`) fixed per cell: the same action and observation delay, as
`quad-sitl --link-impair delay=T` puts T on each direction, and a jitter of ±J per step. Every cell
keeps the success rate (the project's hover rule), the crash rate and the mean hover error over the
last 2 s. The "before" files are the shipped models as they were before training through delay (git
history: `git show REV:models/hover/policy.pt`); the JSON names the revision given with --before-rev.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path

from quadpilot.console import docs_quick, quick
from quadpilot.core.timing import TimingConfig

CELLS = ((0, 0), (10, 0), (10, 10), (20, 0), (20, 10), (30, 10), (40, 0), (40, 10), (50, 0))
"""(delay each way, jitter), ms."""


def grid(path: str, episodes: int) -> list[dict]:
    from quadpilot.train.algorithms import load_policy
    from quadpilot.train.envs.evaluate import evaluate

    policy = load_policy(path)
    rows = []
    for delay, jitter in CELLS:
        cfg = dataclasses.replace(policy.env_config, timing=TimingConfig.fixed(delay, jitter))
        r = evaluate(policy, cfg, episodes=episodes, seed=2024)
        rows.append(
            {
                "delay_ms": delay,
                "jitter_ms": jitter,
                "episodes": r["episodes"],
                "success_rate": r["success_rate"],
                "crash_rate": r["crash_rate"],
                "mean_error_last_window_m": r["mean_error_last_window_m"],
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("policies", nargs="+", metavar="NAME=POLICY.pt")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--before-rev", default="", help="the git revision the 'before' files were taken from")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    episodes = quick(args.episodes, 4)
    todo = []
    for item in args.policies:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            p.error(f"{item!r}: expected NAME=POLICY.pt")
        todo.append((name, path))
    t0 = time.perf_counter()
    out = {}
    for name, path in todo:
        out[name] = {"policy": path, "cells": grid(path, episodes)}
        worst = max(c["crash_rate"] for c in out[name]["cells"])
        print(f"{name}: {len(CELLS)} cells, worst crash rate {worst:.0%}", flush=True)
    doc = {
        "command": " ".join(["python", "benchmarks/delay_grid.py", *(argv if argv is not None else sys.argv[1:])]),
        "before_rev": args.before_rev,
        "machine": {"python": platform.python_version(), "cores": os.cpu_count()},
        "quick": docs_quick(),
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "wall_s": time.perf_counter() - t0,
        "policies": out,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
