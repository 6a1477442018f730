"""A MAVSDK script nobody here wrote, run unchanged against `quad-sitl --realtime --start landed`:
MAVSDK's own Python 4.x example `py/mavsdk/examples/takeoff_and_land.py` (vendored in
tests/sitl/outsider/ with its source and licence). It connects on udpin://0.0.0.0:14540 (fixed in
the script: PX4 SITL's offboard-API port), arms, takes off, lets the vehicle climb for 2 s, sends
land and exits; the vehicle lands and disarms by itself, and quad-sitl ends.

Checked on the vehicle's side (its --tlog: the simulator's HIL_STATE_QUATERNION, the true position;
its --json summary): it left the ground, ended landed and disarmed, within 15 cm of the point it
took off from (where take-off and land sent it: straight up, then down where it is).

MAVSDK-Python's own examples (goto.py, mission.py) are written for the gRPC API of mavsdk < 4 (`from
mavsdk import System`, which 4.x refuses); MAVSDK's 4.x `mission.py`, which flies six waypoints and
returns home, runs unchanged in tests/sitl/test_outsider_mission.py."""

from __future__ import annotations

import hashlib
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mavsdk_gcs import HOME, policy_copy, start_vehicle, stop_vehicle, upstream_part
from pymavlink import mavutil

from quadpilot.link.frames import geodetic_to_local

pytestmark = pytest.mark.sitl
SCRIPT = Path(__file__).parent / "outsider" / "takeoff_and_land.py"
UPSTREAM_SHA256 = "726e2cb272ddb56842e50e6d3872b96ac28f6c6faca80617568133c4cbd22fc4"  # the file at that commit
PORT = 14540  # the script's own
LANDED_M = 0.15


def port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def test_the_vendored_script_is_upstreams_unchanged():
    assert hashlib.sha256(upstream_part(SCRIPT)).hexdigest() == UPSTREAM_SHA256


def test_mavsdks_own_takeoff_and_land_example_flies_the_vehicle_unchanged(tmp_path):
    # the script's port is fixed: a busy one is a failure to see, not a reason to skip a test of outside software
    assert port_free(PORT), f"UDP port {PORT} (fixed in the upstream script) is in use on this machine"
    out, tlog = tmp_path / "summary.json", tmp_path / "flight.tlog"
    vehicle = start_vehicle(policy_copy(tmp_path), PORT, out, duration_s=60, tlog=tlog)
    t0 = time.monotonic()
    try:
        script = subprocess.run(
            [sys.executable, str(SCRIPT)], capture_output=True, text=True, timeout=40, cwd=tmp_path, check=False
        )
    finally:
        code, _, stderr = stop_vehicle(vehicle, timeout=40)
    wall_s = time.monotonic() - t0
    print(script.stdout)
    assert script.returncode == 0, script.stdout + script.stderr
    assert "Mission complete!" in script.stdout  # its last line: arm, takeoff and land were each accepted
    assert code == 0, stderr  # quad-sitl ended on its own: landed and disarmed after a flight
    (c,) = json.loads(out.read_text())["commanded"]
    print(c, f"{wall_s:.1f} s")
    assert not c["armed"] and c["flown"] and c["landed_state"] == "ON_GROUND", c
    assert c["gcs_dropped"] == {}, c  # everything the script's MAVSDK sent was understood

    log = mavutil.mavlink_connection(str(tlog))
    truth = []
    while (m := log.recv_match(type="HIL_STATE_QUATERNION")) is not None:
        truth.append(geodetic_to_local(m.lat, m.lon, m.alt, HOME))
    truth = np.array(truth)
    top, start, end = truth[:, 2].max(), truth[0], truth[-1]
    print(f"highest {top:.2f} m, landed {np.linalg.norm(end - start) * 100:.1f} cm from the take-off point")
    assert top > 1.0  # it flew (2 s of a 1.5 m/s climb, then the landing)
    assert abs(end[2]) < 0.02 and np.linalg.norm(end - start) <= LANDED_M
