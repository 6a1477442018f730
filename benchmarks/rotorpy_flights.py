"""Policies flown by `quad-sitl --node-only` in RotorPy's PX4 simulator (rotorpy 3.0.0 PX4Multirotor with
PX4's SIH quad-X parameters, or RotorPy's Hummingbird), kept as data for docs/airframes.md.

    .venv/bin/python benchmarks/rotorpy_flights.py run docs/bench/rotorpy_flights.json   # about a minute

The flights are tests/sitl/test_rotorpy.py's FLIGHTS, each run exactly as that test runs it (its `fly`:
tests/sitl/rotorpy_px4.py
and quad-sitl in two processes over loopback TCP, RotorPy 5 m up with its rotors at rest, home from the
first fix). Stored per flight: the policy, rate, MAVLink version, the commands, steps and missed steps
(on RotorPy's side of the wire: no answer within its 10 ms, or the previous step's answer), and from
RotorPy's ground truth over the last 2 s: the mean distance to the target, the mean height error, the
mean |yaw rate| and the heading change from the start (yaw from RotorPy's quaternion, scalar-last
x, y, z, w, world ENU, positive counter-clockwise seen from above).

It also holds one flight of benchmarks/airframes.py's RotorPy side (`rotorpy_flight`, `ROTORPY_FLIGHTS`),
measured the same way.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _load_test_module():
    """tests/sitl/test_rotorpy.py, for its `fly` and `RotorPyFlight`: one way to fly RotorPy."""
    spec = importlib.util.spec_from_file_location("rotorpy_flight_test", ROOT / "tests/sitl/test_rotorpy.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def yaw_enu(q: np.ndarray) -> np.ndarray:
    """Yaw (rad, about world Up) of quaternions given scalar-last (x, y, z, w), as RotorPy stores them."""
    x, y, z, w = q.T
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def measure(t, case, rotorpy: dict, summary: dict) -> dict:
    rows = rotorpy["steps"]
    k = round(t.WINDOW_S * case.rate_hz)
    x = np.array([r["x"] for r in rows])
    target = t.rotorpy_target(case.target)  # the node's metres on RotorPy's Earth
    # the start is level, facing East (rotorpy_px4.py's START q = (0, 0, 0, 1)): yaw 0
    yaw = np.unwrap(yaw_enu(np.array([[0.0, 0.0, 0.0, 1.0]] + [r["q"] for r in rows])))
    turned = np.degrees(yaw[1:] - yaw[0])[-k:]  # unwrapped: how far it turned, laps included
    heading = (turned + 180.0) % 360.0 - 180.0  # the heading's difference from the start, (-180, 180]
    return {
        "policy": str(case.policy.relative_to(ROOT)),
        "vehicle": case.vehicle,
        "rate_hz": case.rate_hz,
        "mavlink": case.mavlink,
        "duration_s": case.duration_s,
        "target_enu_m": list(case.target) if case.target is not None else None,
        "steps": len(rows),
        "missed_steps": sum(r["reply_t_us"] != r["t_us"] for r in rows),
        "no_reply_steps": sum(r["reply_t_us"] is None for r in rows),
        "extra_replies": rotorpy["extra_replies"],
        "error_last_2s_m": float(np.linalg.norm(x[-k:] - target, axis=1).mean()),
        "height_error_last_2s_m": float(np.mean(x[-k:, 2] - target[2])),
        "mean_abs_yaw_rate_last_2s": float(np.abs(np.array([r["w"] for r in rows])[-k:, 2]).mean()),
        "turned_last_2s_deg": {"mean": float(turned.mean()), "min": float(turned.min()), "max": float(turned.max())},
        "heading_change_last_2s_deg": {
            "mean": float((turned.mean() + 180.0) % 360.0 - 180.0),
            "min": float(heading.min()),
            "max": float(heading.max()),
        },
        "node": summary,
    }


# --- benchmarks/airframes.py's RotorPy side ---------------------------------------------------

ROTORPY_FLIGHTS = {
    "hover": ["--target=0.6,-0.5,0.55"],
    "step": ["--maneuver", "step"],
    "figure8 1 m/s": ["--maneuver", "figure8:1"],
    "figure8 2 m/s": ["--maneuver", "figure8:2"],
    "figure8 4 m/s": ["--maneuver", "figure8:4"],
    "mass+30%": ["--target=0.6,-0.5,0.55"],
    "mass-30%": ["--target=0.6,-0.5,0.55"],
    "thrust+20%": ["--target=0.6,-0.5,0.55"],
    "thrust-20%": ["--target=0.6,-0.5,0.55"],
    "wind": ["--target=0.6,-0.5,0.55"],
    "impulse": ["--target=0.6,-0.5,0.55"],
}
ROTORPY_SIM = {"wind": ("--wind", "2,0,0", "--gust", "1"), "impulse": ("--impulse", "1@3")}
"""The disturbances in RotorPy (tests/sitl/rotorpy_px4.py's flags), as in our simulator: `wind` a
steady 2 m/s east with gusts of a standard deviation of 1 m/s per axis about it (RotorPy's
SinusoidWind at periods of 2 to 3.4 s; ours: random, correlated over 2 s); `impulse` the velocity
jumping by 1 m/s east 3 s in."""
ROTORPY_DURATION = {"impulse": 7.0}
"""s of a hover flight when not 5 (the impulse: judged over the last 2 s of 7, as in our simulator)."""
ROTORPY_PLANT = {
    "mass+30%": {"mass": 1.3},
    "mass-30%": {"mass": 0.7},
    "thrust+20%": {"k_f": 1.2},
    "thrust-20%": {"k_f": 0.8},
}
"""The wrong-file flights in RotorPy: its plant is the vehicle file scaled so (`VehicleParams.scaled`),
while the policy keeps the file it was made for (RAPTOR: the nominal file's rotor order)."""
ROTORPY_DEFAULT = ("hover", "step", "figure8 1 m/s", "figure8 2 m/s", "figure8 4 m/s")
"""`rotorpy`'s flights when none are named (the wrong-file ones, the wind and the impulse are flown by
name). RotorPy's side (rotorpy 3.0.0 PX4Multirotor, the vehicle file's parameters through
`core.rotorpy_vehicle.rotorpy_params`, 100 Hz, MAVLink 1; tests/sitl/test_rotorpy.py's `fly`): one flight
each from RotorPy's start, 5 m up, level, at rest with its rotors at rest, home from the first fix.
`hover`, the wind, the impulse and the wrong files: to a point 0.95 m away (tests/sitl/test_rotorpy.py's
target), judged on the last 2 s; the maneuvers are flown about the start."""


ATTEMPTS = 3
"""RotorPy flights per cell at most, while its steps go on without the node's answer (airframes.py's
`run_rotorpy`)."""


def rotorpy_flight(t, policy: str, vehicle: str, name: str, tmp: Path) -> dict:
    """The flight `name` in RotorPy (`ROTORPY_FLIGHTS`, with its scaled plant `ROTORPY_PLANT`, its
    disturbance `ROTORPY_SIM` and its length `ROTORPY_DURATION`), measured from RotorPy's own ground
    truth (its positions brought into the node's local frame: metres from the start, on the node's
    Earth)."""
    from quadpilot.core.maneuver import STEP_DISTANCE_M, FigureEight, Step, parse_maneuver
    from quadpilot.core.mission import SUCCESS_TOLERANCE_M

    flight, plant = ROTORPY_FLIGHTS[name], ROTORPY_PLANT.get(name)
    # the node flies a maneuver about its home, the start (the local origin)
    maneuver = (
        dataclasses.replace(parse_maneuver(flight[1]), home=(0.0, 0.0, 0.0)) if flight[0] == "--maneuver" else None
    )
    duration = maneuver.duration_s if maneuver is not None else ROTORPY_DURATION.get(name, 5.0)
    node_flags = (*flight, *(("--vehicle", vehicle) if policy.startswith("raptor:") else ()))
    target = None if maneuver is not None else tuple(float(v) for v in flight[0].split("=")[1].split(","))
    flown = vehicle
    if plant:
        from quadpilot.core.vehicle_file import load_vehicle_file, vehicle_to_toml

        flown = str(tmp / "plant.toml")
        Path(flown).write_text(vehicle_to_toml(load_vehicle_file(vehicle).scaled(**plant)))
    case = t.RotorPyFlight(Path(policy), 100, 1, 0.05, vehicle=flown, duration_s=duration, target=target)
    case = dataclasses.replace(case, node_flags=node_flags, sim_flags=ROTORPY_SIM.get(name, ()))
    try:
        record, summary, _, node = t.fly(case, tmp)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as e:  # the harness's checks (pytest.fail: RotorPy did not finish): a row that says so
        return {"failed": (str(e).strip().splitlines() or [type(e).__name__])[0][:300]}
    rows = record["steps"]
    scale = np.array([t.ROTORPY_EARTH_RADIUS_M / t.EARTH_RADIUS_M] * 2 + [1.0])
    # row j is the state after step j, at (j + 1)·dt: the start (RotorPy's origin, 5 m up) goes first,
    # so that state k is at k·dt, flown on the target of step k, as in quad-sitl's own log
    p = np.vstack([np.zeros(3), (np.array([r["x"] for r in rows]) - np.array([0.0, 0.0, t.START_UP_M])) / scale])
    states = np.zeros((len(p), 12))
    states[:, :3] = p
    k = round(t.WINDOW_S * 100)
    out = {
        "steps": len(rows),
        "missed_steps": sum(r["reply_t_us"] != r["t_us"] for r in rows),
        "node_returncode": node.returncode,
        "fallback_steps": summary.get("fallback_steps"),
    }
    if maneuver is None:
        err = np.linalg.norm(p[-k:] - np.array(target), axis=1).mean()
        out.update(mean_error_last_2s_m=float(err), success=bool(err <= SUCCESS_TOLERANCE_M))
    elif isinstance(maneuver, Step):
        out.update(maneuver.measure(states, 0.01), final_error_m=float(np.linalg.norm(p[-1] - [STEP_DISTANCE_M, 0, 0])))
    else:
        assert isinstance(maneuver, FigureEight)
        ref = np.array([maneuver.target_at(k)[0] for k in range(len(p))])
        out.update(maneuver.measure(states, ref, 0.01))
    return out


def run(out: Path) -> dict:
    t = _load_test_module()
    flights = {case.id: case for case in t.FLIGHTS}
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": "benchmarks/rotorpy_flights.py run " + str(out),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip(),
        "policies": {
            str(case.policy.relative_to(ROOT)): json.loads((case.policy.parent / "config.json").read_text())["command"]
            for case in flights.values()
        },
        "flights": {},
    }
    for name, case in flights.items():
        load_before = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as tmp:
            rotorpy, summary, _, node = t.fly(case, Path(tmp))
        if node.returncode != 0:
            print(f"{name}: quad-sitl exited {node.returncode}: {node.stderr.strip()}", file=sys.stderr)
        row = measure(t, case, rotorpy, summary)
        row["node_returncode"] = node.returncode
        # missed steps depend on the host: RotorPy's own process must run within its 10 ms wait
        row["load_1min"] = {"before": load_before, "after": os.getloadavg()[0]}
        data["flights"][name] = row
        print(
            f"{name}: {row['steps']} steps, missed {row['missed_steps']}, error {row['error_last_2s_m'] * 100:.2f} cm "
            f"(height {row['height_error_last_2s_m'] * 100:+.2f} cm), |yaw rate| {row['mean_abs_yaw_rate_last_2s']:.3f}"
            f" rad/s, heading {row['heading_change_last_2s_deg']['mean']:+.1f}° "
            f"(turned {row['turned_last_2s_deg']['mean']:+.1f}°)"
        )
    out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("run").add_argument("out", type=Path)
    args = p.parse_args(argv)
    run(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
