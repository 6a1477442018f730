"""The shipped policies flown in quad-sitl (lockstep, two processes over loopback): fly them and keep
every summary as data, or print the Markdown table of docs/benchmarks.md from that data.

    .venv/bin/python benchmarks/flights.py run docs/bench/flights.json     # about a minute
    .venv/bin/python benchmarks/flights.py table docs/bench/flights.json

`run` executes each command of FLIGHTS below with `--json` into a temporary file and stores, per
flight, the command, quad-sitl's whole summary (success, errors, steps/s, control-loop latency) and
the 1-minute load average before and after it: success and errors are deterministic for a seed,
speed and latency depend on what else the machine was doing.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLIGHTS = {
    "hover": "quad-sitl models/hover/policy.onnx --episodes 10 --gcs none",
    "hover_ort": "quad-sitl models/hover/policy.onnx --episodes 10 --gcs none --backend onnxruntime",
    "waypoint": "quad-sitl models/waypoint/policy.onnx --episodes 10 --gcs none",
    "circle": "quad-sitl models/circle/policy.onnx --episodes 5 --gcs none",
    "hover_dr": "quad-sitl models/hover_dr/policy.onnx --episodes 10 --gcs none",
    "hover_lstm": "quad-sitl models/hover_lstm/policy.onnx --episodes 10 --gcs none --imu-noise --estimator-noise "
    "--motor-tau 0.03",
    "hover_px4_sih": "quad-sitl models/hover_px4_sih/policy.onnx --episodes 10 --gcs none",
    "hover_hummingbird": "quad-sitl models/hover_hummingbird/policy.onnx --episodes 10 --gcs none",
}
LABELS = {
    "hover": "hover",
    "hover_ort": "hover",
    "waypoint": "waypoint (targets ≤ 2 m)",
    "circle": "circle (two laps)",
    "hover_dr": "hover, domain-randomised",
    "hover_lstm": "hover, LSTM (sensor noise, 30 ms motor lag)",
    "hover_px4_sih": "hover, PX4 SIH quad-X (its own vehicle)",
    "hover_hummingbird": "hover, RotorPy Hummingbird (its own vehicle)",
}


def _git(*args: str) -> str:
    r = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else ""


def run(out: Path) -> dict:
    bin_dir = Path(sys.executable).parent
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        # the code flown: the commit, whether src/ had uncommitted changes, and PYTHONPATH if it
        # pointed the commands elsewhere (e.g. at a `git archive` of the commit)
        "commit": _git("rev-parse", "HEAD"),
        "src_modified": bool(_git("status", "--porcelain", "src")),
        "pythonpath": os.environ.get("PYTHONPATH"),
        "flights": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        for name, cmd in FLIGHTS.items():
            argv = shlex.split(cmd)
            js = Path(tmp) / f"{name}.json"
            load_before = os.getloadavg()[0]
            r = subprocess.run(
                [str(bin_dir / argv[0]), *argv[1:], "--json", str(js)], cwd=ROOT, capture_output=True, text=True
            )
            if r.returncode != 0:
                raise SystemExit(f"flights: `{cmd}` exited with {r.returncode}: {r.stderr.strip()[-300:]}")
            summary = json.loads(js.read_text())
            summary.pop("per_episode", None)
            data["flights"][name] = {
                "command": cmd,
                "load_average_1min": [load_before, os.getloadavg()[0]],
                "summary": summary,
            }
    out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def table(data: dict) -> str:
    lines = [
        "| policy | backend | episodes | success | mean error, last 2 s | worst \\|yaw rate\\|, last 2 s "
        "| worst heading error, last 2 s | steps/s | latency p50 / p99 | load average |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, f in data["flights"].items():
        s = f["summary"]
        load = " → ".join(f"{x:.1f}" for x in f["load_average_1min"])
        lines.append(
            f"| {LABELS.get(name, name)} | {s['backend']} | {s['episodes']} | {100 * s['success_rate']:.0f} % | "
            f"{100 * s['mean_error_last_2s_m']:.2f} cm | {s['max_abs_yaw_rate_last_2s_radps']:.3f} rad/s | "
            f"{s['max_heading_error_last_2s_deg']:.1f}° | {s['steps_per_s']:,.0f} | "
            f"{s['control_latency_p50_us']:.0f} / {s['control_latency_p99_us']:.0f} µs | {load} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("json", type=Path)
    t = sub.add_parser("table")
    t.add_argument("json", type=Path)
    args = p.parse_args(argv)
    if args.cmd == "run":
        data = run(args.json)
    else:
        try:
            data = json.loads(args.json.read_text())
        except (OSError, json.JSONDecodeError) as e:
            print(f"flights: cannot read {args.json}: {e}", file=sys.stderr)
            return 1
    print(table(data), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
