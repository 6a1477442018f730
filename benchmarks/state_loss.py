"""Hover through a silent state stream, in our simulator: the node's estimate, hold and landing.

    .venv/bin/python benchmarks/state_loss.py --out docs/bench/state_loss.json [--episodes 20]
    .venv/bin/python benchmarks/report_state_loss.py docs/bench/state_loss.json   # docs/robustness.md's table

The shipped hover policy (models/hover, numpy backend) flown by the node (`autopilot.node`) against
our simulator in lockstep, in this process, at 100 and 250 Hz, with an ideal IMU and with the seed
vehicle's noisy one (ADIS16448: white noise, turn-on bias and bias random walk, `SimConfig.imu_noise`),
`--episodes` episodes per condition (the simulator's seeded starts: episode k of seed 0, the same
starts in every condition). The state
stream (HIL_STATE_QUATERNION) is withheld by the simulator's `state-dropout` fault while HIL_SENSOR
goes on (`simulator.faults`):

- `dropout 0.5 s`: from 2 s of a 5 s flight; judged by the hover rule (`core.mission.judge`, the
  node's log, whose states repeat the last valid one while none arrive).
- `dropout 5 s` and `dropout never ends`: from 2 s of a 10 s flight; judged on the simulator's
  ground truth (`simulator.records.EpisodeRecord`): the first ground contact's speed and the tilt
  before it, the fastest descent, steps flown with every motor off in the air, a crash.
- `no state at all`: a landed start whose state never comes (3 s): the node must refuse to arm.

Every episode's values are kept in the JSON, and one flight's trace (the endless dropout at 100 Hz
with the noisy IMU, episode 0: the simulator's ground truth and the node's estimate) for the plot
`benchmarks/report_state_loss.py --plot` draws.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import threading
import time
from pathlib import Path

from quadpilot.autopilot.flight_log import episode_summary
from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.console import quick
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.simulator.faults import parse_faults
from quadpilot.sitl import SHIPPED_HOVER

RATES_HZ = (100, 250)
IMUS = {"ideal": False, "noisy": True}
TRACED = ("dropout never ends", 100, "noisy")
"""The flight whose trace the JSON keeps: condition, rate, IMU."""
CONDITIONS = {
    # name: (fault, flight s, start)
    "dropout 0.5 s": ("state-dropout@2s+0.5s", 5.0, "air"),
    "dropout 5 s": ("state-dropout@2s+5s", 10.0, "air"),
    "dropout never ends": ("state-dropout@2s+3600s", 10.0, "air"),
    "no state at all": ("state-dropout@0s+3600s", 3.0, "landed"),
}


def fly(
    fault: str, duration_s: float, start: str, rate_hz: int, episodes: int, imu_noise: bool, trace: bool = False
) -> tuple[list[dict], dict | None]:
    """`episodes` flights of one condition; one dict of values per episode, and episode 0's trace
    (`trace`): the simulator's truth and the node's estimate, per step."""
    cfg = SimConfig(
        listen="tcp:127.0.0.1:0",
        episodes=episodes,
        seed=0,
        dt=1.0 / rate_hz,
        lockstep_timeout_s=5.0,
        start=start,
        sensor_faults=parse_faults(fault),
        imu_noise=imu_noise,
        record_truth=trace,
    )
    records = []
    sim = Simulator(cfg, on_episode=records.append)
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    policy = load_policy(SHIPPED_HOVER, "numpy")
    node = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=duration_s, gcs=None))
    logs = []
    try:
        for _ in range(episodes):
            logs.append(node.fly(SafetyMonitor(policy)))
    finally:
        sim.stop()
        thread.join(10)
    rows = []
    for k, (log, rec) in enumerate(zip(logs, records, strict=True)):
        judged = episode_summary(log, 1.0 / rate_hz)
        td = rec.touchdown
        rows.append(
            {
                "episode": k,
                "hover_rule": bool(judged["success"]),
                "error_last_2s_m": judged.get("mean_error_last_window_m"),
                "crashed": rec.crashed,
                "touchdown_speed_mps": None if td is None else td[1],
                "touchdown_tilt_deg": None if td is None else td[2],
                "max_descent_speed_mps": rec.max_descent_speed,
                "motors_off_airborne_steps": rec.motors_off_airborne_steps,
                "final_height_m": rec.final_state[2],
                "failsafe": log.failsafe,
                "state_lost_steps": log.state_lost_steps,
                "phases": [h[2].split(":")[0] for h in log.handovers if h[1] == "state-loss"],
            }
        )
    if not trace:
        return rows, None
    truth = records[0].truth
    return rows, {
        "t_s": [round(t, 4) for t, _ in truth],
        "z_m": [round(s[2], 4) for _, s in truth],
        "vz_mps": [round(s[5], 4) for _, s in truth],
        "tilt_deg": [round(max(abs(s[6]), abs(s[7])) * 57.29577951308232, 3) for _, s in truth],
        "estimate_t_s": [round(t - logs[0].t[0], 4) for t, _ in logs[0].estimates],
        "estimate_z_m": [round(e[2], 4) for _, e in logs[0].estimates],
        "estimate_vz_mps": [round(e[5], 4) for _, e in logs[0].estimates],
        "phases": [[round(t - logs[0].t[0], 3), why] for t, kind, why in logs[0].handovers if kind == "state-loss"],
    }


def _json_safe(v):
    """NaN (an error nothing was flown for) as null: the file is strict JSON."""
    if isinstance(v, float) and v != v:
        return None
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_json_safe(x) for x in v]
    return v


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="the JSON to write")
    p.add_argument("--episodes", type=int, default=20, help="episodes per condition and rate (default 20)")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error("--episodes must be at least 1")
    args.episodes = quick(args.episodes, 1)  # QUADPILOT_DOCS_QUICK (console.docs_quick): one episode a cell
    t0 = time.perf_counter()
    cells, trace = [], None
    for imu, noisy in IMUS.items():
        for rate in RATES_HZ:
            for name, (fault, duration, start) in CONDITIONS.items():
                c0 = time.perf_counter()
                traced = (name, rate, imu) == TRACED
                rows, tr = fly(fault, duration, start, rate, args.episodes, noisy, trace=traced)
                trace = tr if traced else trace
                cells.append(
                    {"condition": name, "fault": fault, "flight_s": duration, "start": start, "rate_hz": rate}
                    | {"imu": imu, "wall_s": time.perf_counter() - c0, "episodes": rows}
                )
                print(
                    f"{name:>20} at {rate} Hz, {imu} IMU: {sum(r['hover_rule'] for r in rows)}/{len(rows)} hover "
                    f"rule, {sum(r['crashed'] for r in rows)} crashed, {time.perf_counter() - c0:.0f} s",
                    flush=True,
                )
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    out = {
        "command": "benchmarks/state_loss.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "commit": commit,
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "wall_s": time.perf_counter() - t0,
        "cells": cells,
        "trace": {"condition": TRACED[0], "rate_hz": TRACED[1], "imu": TRACED[2], "episode": 0} | trace,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(_json_safe(out), indent=1, allow_nan=False) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
