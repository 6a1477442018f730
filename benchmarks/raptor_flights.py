"""RAPTOR's foundation policy (`quad-sitl raptor:foundation`, the policy PX4's mc_raptor flies) flown
through the px4-raptor contract, kept as data for docs/px4.md:

    .venv/bin/python benchmarks/raptor_flights.py run docs/bench/raptor_flights.json   # a few minutes

- ours, 100 Hz: `quad-sitl raptor:foundation --episodes 10` on PX4's SIH quad-X (the default vehicle
  of a RAPTOR policy), random starts within 1 m of the target, random headings; on the Crazyflie
  preset (which models no rotor lag, cf2x.urdf); and on that preset with a 30 ms first-order rotor
  lag (`motor_tau = 0.03`, a value chosen for this experiment, not identified on a Crazyflie).
- ours, 250 Hz: `quad-sitl --sim-only --rate 250` and `quad-sitl raptor:foundation --node-only
  --target 0.5,-0.3,0.4`: the policy runs at every step, its GRU advancing every second step.
- RotorPy (rotorpy 3.0.0 PX4Multirotor, PX4's SIH quad-X parameters) at 100 Hz (MAVLink 1) and
  250 Hz (MAVLink 2), as tests/sitl/test_rotorpy.py flies it (its `fly`), target (0.6, −0.5, 0.55) m.

Stored per flight: the summary quad-sitl wrote (--json), and for RotorPy its ground truth over the
last 2 s (mean distance to the target, mean |yaw rate|, mean heading error from the start) and the
steps RotorPy flew without our answer in time (missed: the host's load, not the policy).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
QUAD_SITL = [sys.executable, "-m", "quadpilot.sitl", "--gcs", "none"]
SIM_250 = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--rate", "250", "--episodes", "1"]
LAG_S = 0.03


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def quad_sitl(args: list[str], tmp: Path, policy: tuple[str, ...] = ("raptor:foundation",)) -> dict:
    """One `quad-sitl` run of `policy` (its argument: a file, a name, or [] with --model) and its --json summary."""
    out = tmp / "s.json"
    cmd = [*QUAD_SITL, *policy, *args, "--json", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise SystemExit(f"quad-sitl {' '.join(args)} exited {done.returncode}: {done.stderr.strip()}")
    return json.loads(out.read_text())


def ours(vehicle: str, episodes: int, tmp: Path) -> dict:
    return quad_sitl(["--episodes", str(episodes), "--vehicle", vehicle], tmp)


def crazyflie_with_lag(tmp: Path) -> str:
    """The Crazyflie preset's vehicle file with a rotor time constant of LAG_S."""
    text = (ROOT / "src/quadpilot/vehicles/crazyflie.toml").read_text()
    lines = [f"motor_tau = {LAG_S}" if line.startswith("motor_tau") else line for line in text.splitlines()]
    lines = ['name = "crazyflie_lag30ms"' if line.startswith("name") else line for line in lines]
    path = tmp / "crazyflie_lag30ms.toml"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def ours_250(tmp: Path) -> dict:
    port = _free_port()
    sim = subprocess.Popen(
        [*SIM_250, "--listen", f"tcp:127.0.0.1:{port}", "--vehicle", "px4_sih_quadx"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        node = ["--node-only", "--connect", f"tcp:127.0.0.1:{port}", "--duration", "5", "--target=0.5,-0.3,0.4"]
        return quad_sitl(node, tmp)
    finally:
        sim.wait(timeout=60)


def rotorpy(rate: int, mavlink: int, tmp: Path, policy: str = "raptor:foundation", vehicle: str = "sih") -> dict:
    """One flight of `policy` in RotorPy's PX4 simulator (`vehicle`: its sih or hummingbird airframe), as
    tests/sitl/test_rotorpy.py flies it, and RotorPy's ground truth over the last 2 s."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rotorpy_flight_test", ROOT / "tests/sitl/test_rotorpy.py")
    t = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(t)
    case = t.RotorPyFlight(Path(policy), rate, mavlink, max_error_m=0.1, vehicle=vehicle, target=(0.6, -0.5, 0.55))
    record, summary, _, node = t.fly(case, tmp)
    if node.returncode != 0:
        raise SystemExit(f"RotorPy flight at {rate} Hz: quad-sitl exited {node.returncode}: {node.stderr.strip()}")
    rows = record["steps"]
    k = round(t.WINDOW_S * rate)
    target = t.rotorpy_target(case.target)
    x = np.array([r["x"] for r in rows])
    return {
        "policy": policy,
        "vehicle": vehicle,
        "rate_hz": rate,
        "mavlink": mavlink,
        "target_enu_m": list(case.target),
        "steps": len(rows),
        "missed_steps": sum(r["reply_t_us"] != r["t_us"] for r in rows),
        "error_last_2s_m": float(np.linalg.norm(x[-k:] - target, axis=1).mean()),
        "mean_abs_yaw_rate_last_2s": float(np.abs(np.array([r["w"] for r in rows])[-k:, 2]).mean()),
        "mean_heading_error_last_2s_deg": float(
            np.degrees(np.abs(t.rotorpy_yaw(np.array([r["q"] for r in rows])[-k:]))).mean()
        ),
        "node": summary,
    }


def run(out: Path) -> dict:
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": "benchmarks/raptor_flights.py run " + str(out),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "load_1min_before": os.getloadavg()[0],
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip(),
        "flights": {},
    }
    flights = data["flights"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        flights["ours_100hz_px4_sih_quadx"] = ours("px4_sih_quadx", 10, tmp)
        flights["ours_100hz_crazyflie"] = ours("crazyflie", 5, tmp)
        flights["ours_100hz_crazyflie_lag30ms"] = ours(crazyflie_with_lag(tmp), 5, tmp)
        flights["ours_250hz_px4_sih_quadx"] = ours_250(tmp)
        for rate, mavlink in ((100, 1), (250, 2)):
            with tempfile.TemporaryDirectory() as rp:
                flights[f"rotorpy_{rate}hz_sih"] = rotorpy(rate, mavlink, Path(rp))
    data["load_1min_after"] = os.getloadavg()[0]
    for name, f in flights.items():
        err = f.get("mean_error_last_2s_m", f.get("error_last_2s_m"))
        print(f"{name}: error last 2 s {err * 100:.2f} cm, success {f.get('success_rate', '-')}")
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
