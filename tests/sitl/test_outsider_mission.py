"""A MAVSDK mission script nobody here wrote, run unchanged against `quad-sitl --realtime --start
landed`: MAVSDK's own Python 4.x example `py/mavsdk/examples/mission.py` (vendored in
tests/sitl/outsider/ with its source and licence), given the connection URL it takes as its argument.
It uploads six waypoints 10 m above home (the first 48 m from home, the others 11-18 m apart; each
with a speed, gimbal angles and a camera action, which MAVSDK's Mission plugin turns into
DO_CHANGE_SPEED, DO_GIMBAL_MANAGER_* and IMAGE_/VIDEO_ items: 25 MAVLink items), arms, starts the
mission from the ground, pauses it for 5 s once the third waypoint is current, resumes, waits for the
end, commands Return and exits once the vehicle has disarmed.

Checked on the vehicle's side (its --tlog: the items as uploaded, the MISSION_ITEM_REACHED it sent,
the simulator's HIL_STATE_QUATERNION, the true position; its --json summary): every item reported
reached, in order; the vehicle came within 15 cm of each waypoint while flying to it (the script's
acceptance radius is 1 m: that is where the vehicle reports it reached); it ended landed and
disarmed within 15 cm of home, where Return sent it.

About 260 s of wall time (measured: 147 s to the mission's end, ~1 m/s along its 48 m first leg,
then Return's climb to 30 m, the way home, the descent and landing): marked slow."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mavsdk_gcs import HOME, free_udp_port, policy_copy, start_vehicle, stop_vehicle, upstream_part
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from quadpilot.link.frames import geodetic_to_local

pytestmark = pytest.mark.sitl
SCRIPT = Path(__file__).parent / "outsider" / "mission.py"
UPSTREAM_SHA256 = "bbbc01b006ebc0381d007a705a0190dc93164cb9b0592e1871c60124f6bc4af2"  # the file at that commit
NEAR_M = 0.15
ACCEPTANCE_M = 1.0  # the script's MissionItem.acceptance_radius_m


def test_the_vendored_mission_script_is_upstreams_unchanged():
    assert hashlib.sha256(upstream_part(SCRIPT)).hexdigest() == UPSTREAM_SHA256


def read_tlog(path: Path):
    """Uploaded items by seq; by seq, the index into the truth of the first MISSION_ITEM_REACHED;
    the truth: simulated times (n,) s and positions (n, 3) ENU from home."""
    log = mavutil.mavlink_connection(str(path))
    items, reached, times, truth = {}, {}, [], []
    while (m := log.recv_match()) is not None:
        kind = m.get_type()
        if kind == "MISSION_ITEM_INT":
            items[m.seq] = m
        elif kind == "MISSION_ITEM_REACHED":
            reached.setdefault(m.seq, len(truth) - 1)
        elif kind == "HIL_STATE_QUATERNION":
            times.append(m.time_usec * 1e-6)
            truth.append(geodetic_to_local(m.lat, m.lon, m.alt, HOME))
    return items, reached, np.array(times), np.array(truth)


@pytest.mark.slow  # ~260 s of real time
def test_mavsdks_own_mission_example_flies_the_vehicle_unchanged(tmp_path):
    port = free_udp_port()
    out, tlog = tmp_path / "summary.json", tmp_path / "flight.tlog"
    vehicle = start_vehicle(policy_copy(tmp_path), port, out, duration_s=480, tlog=tlog)
    t0 = time.monotonic()
    try:
        script = subprocess.run(
            [sys.executable, str(SCRIPT), f"udpin://127.0.0.1:{port}"],
            capture_output=True,
            text=True,
            timeout=420,
            cwd=tmp_path,
            check=False,
        )
    finally:
        code, _, stderr = stop_vehicle(vehicle, timeout=60)
    wall_s = time.monotonic() - t0
    print(script.stdout)
    assert script.returncode == 0, script.stdout + script.stderr
    assert "Pausing mission..." in script.stdout and "Continuing mission..." in script.stdout
    assert script.stdout.rstrip().endswith("Disarmed, exiting.")  # its last line: Return ended disarmed
    assert code == 0, stderr  # quad-sitl ended on its own: landed and disarmed after a flight
    (c,) = json.loads(out.read_text())["commanded"]
    print(c, f"{wall_s:.1f} s")
    assert not c["armed"] and c["flown"] and c["landed_state"] == "ON_GROUND", c
    assert c["gcs_dropped"] == {}, c  # everything the script's MAVSDK sent was understood

    items, reached, times, truth = read_tlog(tlog)
    commands = [items[s].command for s in sorted(items)]
    assert sorted(items) == list(range(25)) and M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE in commands
    assert list(reached) == list(range(25))  # every item reported reached, in order
    waypoints = [s for s in sorted(items) if items[s].command == M.MAV_CMD_NAV_WAYPOINT]
    assert len(waypoints) == 6
    start = 0  # from the waypoint before (or take-off) to 2 s after this one was reported reached:
    # at 1 m acceptance the vehicle reports it on its way in; it is closest just after, as the target
    # leaves for the next waypoint (or holds there, after the last)
    for s in waypoints:
        it = items[s]
        goal = geodetic_to_local(it.x, it.y, round(HOME.alt_m * 1000.0), HOME)
        goal[2] = it.z  # frame 6: above home
        end = int(np.searchsorted(times, times[reached[s]] + 2.0))
        d = np.linalg.norm(truth[start:end] - goal, axis=1)
        at_reached = float(np.linalg.norm(truth[reached[s]] - goal))
        print(f"waypoint {s}: closest {d.min() * 100:.1f} cm, {at_reached * 100:.1f} cm when reported reached")
        assert d.min() <= NEAR_M and at_reached <= ACCEPTANCE_M
        start = reached[s]
    top, land = truth[:, 2].max(), truth[-1]
    print(f"highest {top:.2f} m, landed {np.linalg.norm(land) * 100:.1f} cm from home, {wall_s:.0f} s")
    assert abs(land[2]) < 0.02 and np.linalg.norm(land) <= NEAR_M  # Return sends it home (0, 0, 0)
