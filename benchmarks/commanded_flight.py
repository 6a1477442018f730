"""One commanded flight, measured and kept as data, or its table for docs/ground_station.md.

    .venv/bin/python benchmarks/commanded_flight.py run docs/bench/commanded_flight.json   # about 40 s
    .venv/bin/python benchmarks/commanded_flight.py table docs/bench/commanded_flight.json

`run` does what tests/sitl/test_commanded_flight.py does, with the same code (its `commanded_flight`
and the helpers of tests/sitl/mavsdk_gcs.py): `quad-sitl models/hover/policy.onnx --realtime --start
landed --gcs udp:127.0.0.1:PORT` (a copy of the shipped model) commanded by MAVSDK 4.x: a take-off
refused while disarmed, arm, take-off altitude 2.5 m, take off, go 3 m east, a 3-item mission,
land, wait for the disarm. It stores what MAVSDK measured (positions from GLOBAL_POSITION_INT at
20 Hz, host clock) and the vehicle's own summary (`quad-sitl --json`). Real time: the figures
depend on the machine's load, which is recorded with them.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as _dt
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LEGS = {
    "takeoff": "take-off to 2.5 m",
    "goto": "goto 3 m east",
    "item0": "mission item 1",
    "item1": "mission item 2",
    "item2": "mission item 3",
    "mission_end": "mission end (item 3)",
}


def run(out: Path) -> int:
    sys.path.insert(0, str(ROOT / "tests" / "sitl"))  # the commanded-flight test and its kit
    from mavsdk_gcs import free_udp_port, policy_copy, start_vehicle, stop_vehicle
    from test_commanded_flight import GOTO, TAKEOFF, WAYPOINTS, commanded_flight

    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        port = free_udp_port()
        start = time.monotonic()
        proc = start_vehicle(policy_copy(tmp), port, tmp / "summary.json")
        try:
            seen = asyncio.run(asyncio.wait_for(commanded_flight(port), 80))
        finally:
            code, _, stderr = stop_vehicle(proc)
        wall = time.monotonic() - start
        if code != 0:
            print(f"quad-sitl exited with {code}: {stderr.strip().splitlines()[-1:]}", file=sys.stderr)
            return 1
        summary = json.loads((tmp / "summary.json").read_text())
    seen = {k: (v.name if hasattr(v, "name") else v) for k, v in seen.items()}
    # the goto's mean speed: its distance over the time from the command to the stop
    seen["goto_mean_speed_m_s"] = float(((GOTO - TAKEOFF) ** 2).sum() ** 0.5) / seen["goto_s"]
    data = {
        "command": "quad-sitl models/hover/policy.onnx --realtime --start landed --duration 90 "
        "--gcs udp:127.0.0.1:PORT",
        "client": "MAVSDK-Python 4.x, tests/sitl/test_commanded_flight.py commanded_flight",
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform()},
        "load_1min": {"before": load_before, "after": os.getloadavg()[0]},
        "wall_s": wall,
        "goals_enu_m": {"takeoff": TAKEOFF.tolist(), "goto": GOTO.tolist(), "mission": WAYPOINTS.tolist()},
        "measured": seen,
        "vehicle": {
            k: summary[k]
            for k in ("steps", "control_latency_p50_us", "control_latency_p99_us", "fallback_steps", "failsafe_events")
            if k in summary
        }
        | {"commanded": summary.get("commanded")},
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {out} ({wall:.0f} s)")
    return 0


def table(path: Path) -> int:
    m = json.loads(path.read_text())["measured"]
    print("| leg | arrival error | largest error over the next 2 s of hold |")
    print("|---|---|---|")
    for key, label in LEGS.items():
        arr, hold = m["arrival_m"].get(key), m["hold_max_m"].get(key)
        cell = lambda v: "" if v is None else f"{v * 100:.1f} cm"  # noqa: E731
        print(f"| {label} | {cell(arr)} | {cell(hold)} |")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("run", "table"))
    p.add_argument("json", type=Path)
    a = p.parse_args(argv)
    if a.what == "table":
        try:
            return table(a.json)
        except (OSError, json.JSONDecodeError, KeyError) as e:
            print(f"cannot read {a.json}: {e}", file=sys.stderr)
            return 1
    return run(a.json)


if __name__ == "__main__":
    sys.exit(main())
