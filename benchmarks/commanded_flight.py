"""One commanded flight, measured and kept as data, or its table for docs/ground_station.md.

    .venv/bin/python benchmarks/commanded_flight.py run docs/bench/commanded_flight.json   # about 40 s
    .venv/bin/python benchmarks/commanded_flight.py table docs/bench/commanded_flight.json

`run` also writes the flight's path beside the JSON (commanded_flight_trace.csv, `TRACE_COLUMNS`,
10 Hz of simulated time), which docs/ground_station_gif.py draws.

`run` does what tests/sitl/test_commanded_flight.py does, with the same code (its `commanded_flight`
and the helpers of tests/sitl/mavsdk_gcs.py): `quad-sitl models/hover/policy.onnx --realtime --start
landed --gcs udp:127.0.0.1:PORT` (a copy of the shipped model) commanded by MAVSDK 4.x: a take-off
refused while disarmed, arm, take-off altitude 2.5 m, take off, go 3 m east, a 3-item mission,
land, wait for the disarm. It stores what MAVSDK measured (positions from GLOBAL_POSITION_INT at
20 Hz, host clock) and the vehicle's own summary (`quad-sitl --json`). Real time: the figures
depend on the machine's load, which is recorded with them.

The path comes from the vehicle's own MAVLink log (`quad-sitl --tlog`: every message on its
simulator and ground-station links, in the order the node handled them): positions and yaw from the
simulator's HIL_STATE_QUATERNION (each step, time_usec is simulated time); the phase from what the
vehicle answered the ground station: each accepted command (COMMAND_ACK ACCEPTED, paired with the
COMMAND_LONG/INT it answers), MISSION_ITEM_REACHED, the STATUSTEXTs "Mission finished", "Landing
detected" and "Disarmed ...", and the end of the take-off (its HEARTBEAT's mode going from Takeoff to
Hold, 1 Hz as PX4 sends it, so up to 1 s late); `armed` and `mode` are its last HEARTBEAT's, as a
ground station sees them. Each message is put at the simulated time of the last state the node had
received before it.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
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
TRACE_HZ = 10.0
"""Rows per simulated second in the trace CSV: enough to draw the path, small enough to commit."""
TRACE_COLUMNS = ("t_s", "east_m", "north_m", "up_m", "yaw_rad", "armed", "mode", "phase")
"""t_s simulated time since the simulator started; east, north, up in m from home (ENU); yaw in rad
(ENU, 0 facing east); armed 0/1 and mode (PX4 mode name) from the vehicle's last HEARTBEAT; phase:
disarmed, armed, take-off, hold, goto, mission item K, land, return, landed."""
SIM_SYSTEM, VEHICLE_SYSTEM = 200, 1  # our simulator's MAVLink system id, the node's (docs/architecture.md)


def run(out: Path) -> int:
    sys.path.insert(0, str(ROOT / "tests" / "sitl"))  # the commanded-flight test and its kit
    from mavsdk_gcs import free_udp_port, policy_copy, start_vehicle, stop_vehicle
    from test_commanded_flight import GOTO, TAKEOFF, WAYPOINTS, commanded_flight

    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        port = free_udp_port()
        start = time.monotonic()
        proc = start_vehicle(policy_copy(tmp), port, tmp / "summary.json", tlog=tmp / "flight.tlog")
        try:
            seen = asyncio.run(asyncio.wait_for(commanded_flight(port), 80))
        finally:
            code, _, stderr = stop_vehicle(proc)
        wall = time.monotonic() - start
        if code != 0:
            print(f"quad-sitl exited with {code}: {stderr.strip().splitlines()[-1:]}", file=sys.stderr)
            return 1
        summary = json.loads((tmp / "summary.json").read_text())
        try:
            rows, phases = trace_from_tlog(tmp / "flight.tlog")
        except (OSError, ValueError) as e:
            print(f"cannot read the vehicle's MAVLink log: {e}", file=sys.stderr)
            return 1
    seen = {k: (v.name if hasattr(v, "name") else v) for k, v in seen.items()}
    # the goto's mean speed: its distance over the time from the command to the stop
    seen["goto_mean_speed_m_s"] = float(((GOTO - TAKEOFF) ** 2).sum() ** 0.5) / seen["goto_s"]
    data = {
        "command": "quad-sitl models/hover/policy.onnx --realtime --start landed --duration 90 "
        "--gcs udp:127.0.0.1:PORT --tlog TMP.tlog",
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
        "trace": {
            "csv": trace_path(out).name,
            "rate_hz": TRACE_HZ,
            "columns": list(TRACE_COLUMNS),
            "phases_s": phases,
        },
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1) + "\n")
    write_trace(rows, trace_path(out))
    print(f"wrote {out} and {trace_path(out)} ({wall:.0f} s)")
    return 0


def trace_path(json_path: Path) -> Path:
    """docs/bench/commanded_flight.json → docs/bench/commanded_flight_trace.csv."""
    return json_path.with_name(f"{json_path.stem}_trace.csv")


# Phase of an accepted command, by MAV_CMD id (MAVLink common.xml); DO_SET_MODE by PX4 mode below.
COMMAND_PHASES = {22: "take-off", 192: "goto", 21: "land", 20: "return", 300: "mission item 1"}
MODE_PHASES = {"Takeoff": "take-off", "Mission": "mission item 1", "Land": "land", "Return": "return", "Hold": "hold"}
ARM_DISARM, SET_MODE = 400, 176
NAV_ITEMS = {
    16,
    20,
    21,
    22,
}  # NAV_WAYPOINT, RETURN_TO_LAUNCH, LAND, TAKEOFF: the items autopilot/mission_protocol.py flies


def trace_from_tlog(path: Path) -> tuple[list[list], list[list]]:
    """The vehicle's .tlog → (rows of `TRACE_COLUMNS` at `TRACE_HZ`, [[t_s, phase], ...] at every
    change of phase). See the module docstring for where each value comes from."""
    from pymavlink import mavutil

    from quadpilot.autopilot.modes import MODE_NAMES
    from quadpilot.link.frames import Home
    from quadpilot.link.wire import state_from_hil_state_quaternion

    home = Home()  # the simulator's home, as in tests/sitl/mavsdk_gcs.py
    names = {(int(main), int(sub)): name for (main, sub), name in MODE_NAMES.items()}
    log = mavutil.mavlink_connection(str(path), dialect="common")
    t = None  # simulated time of the last state, s
    armed, mode, phase = 0, "", "disarmed"
    asked: dict[int, object] = {}  # MAV_CMD id → the ground station's last COMMAND_LONG/INT of it
    reached: set[int] = set()
    places: list[int] = []  # seq of the uploaded mission's position items (MAVSDK adds DO_CHANGE_SPEED ones)
    rows: list[list] = []
    phases: list[list] = []
    next_row = 0.0

    def enter(new: str) -> None:
        nonlocal phase
        if new != phase and t is not None:
            phase = new
            phases.append([round(t, 3), new])

    while (m := log.recv_match()) is not None:
        kind, src = m.get_type(), m.get_srcSystem()
        if kind == "HIL_STATE_QUATERNION" and src == SIM_SYSTEM:
            t = m.time_usec * 1e-6
            if t + 1e-9 >= next_row:
                s = state_from_hil_state_quaternion(m, home)
                rows.append([t, s[0], s[1], s[2], s[8], armed, mode, phase])
                next_row = (round(t * TRACE_HZ) + 1) / TRACE_HZ
        elif kind in ("COMMAND_LONG", "COMMAND_INT") and m.target_system == VEHICLE_SYSTEM:
            asked[m.command] = m
        elif kind == "MISSION_COUNT" and m.target_system == VEHICLE_SYSTEM:
            places = []
        elif kind == "MISSION_ITEM_INT" and m.target_system == VEHICLE_SYSTEM and m.command in NAV_ITEMS:
            places = sorted({*places, m.seq})
        elif src != VEHICLE_SYSTEM:
            continue
        elif kind == "COMMAND_ACK" and m.result == mavutil.mavlink.MAV_RESULT_ACCEPTED and m.command in asked:
            c = asked[m.command]
            if m.command == ARM_DISARM:
                enter("armed" if c.param1 == 1 else "disarmed")
            elif m.command == SET_MODE and names.get((int(c.param2), int(c.param3))) in MODE_PHASES:
                enter(MODE_PHASES[names[(int(c.param2), int(c.param3))]])
            elif m.command in COMMAND_PHASES:
                enter(COMMAND_PHASES[m.command])
            if phase == "mission item 1":
                reached.clear()
        elif kind == "MISSION_ITEM_REACHED" and m.seq in places and m.seq not in reached:  # PX4 repeats it
            reached.add(m.seq)
            k = places.index(m.seq) + 1  # position items reached so far: MAVSDK's mission progress
            if k < len(places):  # the last one: "Mission finished" follows
                enter(f"mission item {k + 1}")
        elif kind == "STATUSTEXT":
            text = m.text
            if text.startswith("Mission finished"):
                enter("hold")
            elif text.startswith("Landing detected"):
                enter("landed")
            elif text.startswith("Disarmed"):
                enter("disarmed")
        elif kind == "HEARTBEAT" and m.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4:
            new = names.get(((m.custom_mode >> 16) & 0xFF, m.custom_mode >> 24), "")
            if phase == "take-off" and mode == "Takeoff" and new == "Hold":
                enter("hold")
            armed = int(bool(m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
            mode = new
    if not rows:
        raise ValueError(f"{path}: no HIL_STATE_QUATERNION from the simulator (system {SIM_SYSTEM})")
    return rows, phases


def write_trace(rows: list[list], path: Path) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(TRACE_COLUMNS)
        for t, e, n, u, yaw, armed, mode, phase in rows:
            w.writerow([f"{t:.2f}", f"{e:.3f}", f"{n:.3f}", f"{u:.3f}", f"{yaw:.3f}", armed, mode, phase])


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
