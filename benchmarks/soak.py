"""Soak: a long run of the node against the simulator process, watching memory, drops and step times.

    .venv/bin/python benchmarks/soak.py --steps 1000000 --out docs/bench/soak_lockstep.json
    .venv/bin/python benchmarks/soak.py --realtime --seconds 1800 --out docs/bench/soak_realtime.json

The simulator runs as its own process (`python -m quadpilot.simulator --sim-only`, as quad-sitl
starts it) and the node (`autopilot.node.Node`, the shipped hover policy, numpy backend) in this one,
over loopback TCP at 100 Hz, for `--episodes` back-to-back episodes (one connection each, as quad-sitl
flies them) that add up to `--steps` lockstep steps or `--seconds` of real time. After every episode it
records the resident set size (VmRSS, /proc) of both processes; the growth is the last episode's RSS
minus the first's (the first episode is the warm-up: imports, caches and the allocator's arenas fill
there). Step times are the node's periods between consecutive HIL_SENSOR arrivals (`EpisodeLog.wall`),
kept in one array allocated before the first episode. The node's RSS is read twice: as it is, and
after glibc's malloc_trim (the flight log of each episode is freed, and glibc keeps freed heap; the
trimmed figure is what is still held, which a leak would grow); "lost steps" are steps the simulator advanced
that the node never answered (simulator steps − node replies, per episode, at least 0: the node
answers step 0 too, and leaves with the simulator's last step in flight), and the packets either
side dropped are both sides' counters. Goals: RSS growth ≤ 2 MiB per process, zero lost steps.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from link_faults import machine
from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.console import quick
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.sitl import SHIPPED_HOVER
from quadpilot.sitl.simulator_process import start_simulator

RATE_HZ = 100
QUICK_EPISODES, QUICK_EPISODE_S = 2, 2


def _malloc_trim():
    """glibc's malloc_trim(3), or None: the node's flight log (one entry per step, ~100,000 an
    episode here) is freed after each episode, and glibc keeps much of the freed heap; the RSS after a
    trim is the memory still held, which is what a leak would grow."""
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


_trim = _malloc_trim()
GOAL_RSS_GROWTH_MIB = 2.0


def rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for process {pid}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--realtime", action="store_true", help="real time instead of lockstep")
    p.add_argument("--steps", type=int, default=1_000_000, help="lockstep steps in all (default 1,000,000)")
    p.add_argument("--seconds", type=float, default=1800.0, help="real-time seconds in all (default 1800)")
    p.add_argument("--episodes", type=int, default=10, help="episodes the run is cut into (default 10)")
    p.add_argument("--note", default="", help="a line on the machine's state")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    # QUADPILOT_DOCS_QUICK (console.docs_quick): two episodes of 2 s, as a smoke test of the script
    args.steps, args.seconds = (
        quick(args.steps, QUICK_EPISODES * QUICK_EPISODE_S * RATE_HZ),
        quick(args.seconds, QUICK_EPISODES * QUICK_EPISODE_S),
    )
    args.episodes = quick(args.episodes, QUICK_EPISODES)
    total_s = args.seconds if args.realtime else args.steps / RATE_HZ
    episode_s = total_s / args.episodes
    steps_per_episode = round(episode_s * RATE_HZ)
    stats_path = args.out.with_suffix(".sim-stats.tmp.json")
    cmd = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", "tcp:127.0.0.1:0"]
    cmd += ["--realtime" if args.realtime else "--lockstep"]  # serves until stopped: its RSS is read after the last
    cmd += ["--max-steps", str(steps_per_episode + 10), "--json", str(stats_path)]
    # the simulator writes its --json when SIGINT stops it; a job started in the background (CI) has
    # SIGINT ignored, which a child inherits: it gets Python's own handler for the start instead
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc, address = start_simulator(cmd)
    finally:
        signal.signal(signal.SIGINT, before)
    if proc is None:
        print(f"soak: the simulator did not start: {address}", file=sys.stderr)
        return 1
    monitor = SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
    node = Node(NodeConfig(connect=address, duration_s=episode_s, lockstep=not args.realtime, gcs=None))
    periods = np.full(steps_per_episode * args.episodes, np.nan, np.float32)  # before any RSS is taken
    filled = 0
    episodes = []
    t0 = time.perf_counter()
    try:
        for k in range(args.episodes):
            log = node.fly(monitor)
            d = np.diff(np.asarray(log.wall))
            n = min(len(d), len(periods) - filled)
            periods[filled : filled + n] = d[:n]
            filled += n
            first = {
                "episode": k,
                "replies": log.replies,
                "steps_logged": log.steps,
                "failsafe": log.failsafe,
                "node_dropped": dict(log.dropped),
                "fallback_steps": sum(1 for s in log.sources if s != "policy"),
                "wall_s": log.wall_s,
            }
            del log, d
            gc.collect()
            # the row kept is a copy made now: made while the flight log still filled the heap, it would
            # land in a fresh pymalloc arena (1 MiB) and keep it from being freed, which is this
            # script's memory and not the node's (measured: +1 arena per long episode with the row
            # made then, none with the copy)
            row = json.loads(json.dumps(first))
            del first
            gc.collect()
            row["node_rss_mib"], row["sim_rss_mib"] = rss_mib(os.getpid()), rss_mib(proc.pid)
            if _trim is not None:  # what the freed flight log leaves in the heap goes back to the system
                _trim(0)
                row["node_rss_trimmed_mib"] = rss_mib(os.getpid())
            episodes.append(row)
            print(
                f"episode {k}: {row['replies']:,} steps, node RSS {row['node_rss_mib']:.1f} MiB "
                f"(trimmed {row.get('node_rss_trimmed_mib', math.nan):.1f}), "
                f"simulator RSS {row['sim_rss_mib']:.1f} MiB, "
                f"failsafe {row['failsafe']}",
                flush=True,
            )
    finally:
        proc.send_signal(signal.SIGINT)  # it writes its --json on the way out
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    wall = time.perf_counter() - t0
    sim = json.loads(stats_path.read_text()) if stats_path.exists() else {"records": []}
    stats_path.unlink(missing_ok=True)
    for row, rec in zip(episodes, sim["records"], strict=False):
        row["sim_steps"] = rec["steps"]
        row["sim_end"] = rec["end_reason"]
        row["sim_dropped"] = rec["dropped"]
        row["sim_overruns"] = rec["overruns"]
        row["lost_steps"] = max(0, rec["steps"] - row["replies"])  # the last step may be in flight as the node leaves
    ms = periods[:filled].astype(np.float64) * 1e3
    pct = {f"p{q:g}": float(np.percentile(ms, q)) for q in (50, 90, 99, 99.9)} if filled else {}
    first, last = episodes[0], episodes[-1]
    doc = {
        "command": " ".join(["python", "benchmarks/soak.py", *(argv if argv is not None else sys.argv[1:])]),
        "mode": "realtime" if args.realtime else "lockstep",
        "machine": machine() | {"load_average_1min_at_end": os.getloadavg()[0]},
        "note": args.note,
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "rate_hz": RATE_HZ,
        "episodes": episodes,
        "steps": int(sum(r["replies"] for r in episodes)),
        "sim_steps": int(sum(r.get("sim_steps", 0) for r in episodes)),
        "wall_s": wall,
        "node_rss_growth_mib": last["node_rss_mib"] - first["node_rss_mib"],
        "node_rss_trimmed_growth_mib": (
            last["node_rss_trimmed_mib"] - first["node_rss_trimmed_mib"] if "node_rss_trimmed_mib" in first else None
        ),
        "sim_rss_growth_mib": last["sim_rss_mib"] - first["sim_rss_mib"],
        "lost_steps": int(sum(r.get("lost_steps", 0) for r in episodes)),
        "failsafes": sum(r["failsafe"] is not None for r in episodes),
        "node_dropped": int(sum(sum(r["node_dropped"].values()) for r in episodes)),
        "sim_dropped": int(sum(sum(r.get("sim_dropped", {}).values()) for r in episodes)),
        "sim_overruns": int(sum(r.get("sim_overruns", 0) for r in episodes)),
        "step_time_ms": pct | {"max": float(ms.max()) if filled else None, "n": int(filled)},
        "goal_rss_growth_mib": GOAL_RSS_GROWTH_MIB,
    }
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(
        f"soak: {doc['steps']:,} steps in {wall:.0f} s; RSS growth node {doc['node_rss_growth_mib']:+.2f} MiB "
        f"(after malloc_trim {doc['node_rss_trimmed_growth_mib'] or math.nan:+.2f} MiB), "
        f"simulator {doc['sim_rss_growth_mib']:+.2f} MiB; lost steps {doc['lost_steps']}, failsafes {doc['failsafes']}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
