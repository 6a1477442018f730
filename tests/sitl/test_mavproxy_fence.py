"""MAVProxy connecting to the vehicle hears no "fence breach": the vehicle has no geofence, and its
SYS_STATUS says so the way MAVProxy's fence module reads it (the geofence bit healthy, not present,
not enabled). MAVProxy's fence module (MAVProxy/modules/mavproxy_fence.py, `handle_sys_status`)
starts from "healthy" and says "fence breach" on the first SYS_STATUS whose geofence health bit is
clear, fence or none. Both the vehicle a ground station commands (`--start landed`) and the
telemetry-only one (a scripted flight with `--gcs`). Real MAVProxy, as tests/sitl/test_mavproxy.py
drives it."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from mavsdk_gcs import free_udp_port, policy_copy, start_vehicle, stop_vehicle
from test_mavproxy import Console, mavproxy_path

pytestmark = pytest.mark.sitl


def _telemetry_only(policy, port: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "quadpilot.sitl", str(policy), "--realtime", "--episodes", "1", "--duration", "20"]
    cmd += ["--gcs", f"udp:127.0.0.1:{port}"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize("vehicle", ["commanded", "telemetry only"])
def test_mavproxy_hears_no_fence_breach_from_a_vehicle_without_a_fence(tmp_path, vehicle):
    exe = mavproxy_path()
    if exe is None:
        pytest.fail('MAVProxy not found: the dev extra installs it (pip install -e ".[dev]"), or set $MAVPROXY')
    port = free_udp_port()
    policy = policy_copy(tmp_path)
    if vehicle == "commanded":
        proc = start_vehicle(policy, port, tmp_path / "summary.json", duration_s=30)
    else:
        proc = _telemetry_only(policy, port)
    console = Console(exe, port, tmp_path)
    try:
        console.expect(r"Detected vehicle 1:1", 20)
        time.sleep(3.0)  # SYS_STATUS at 1 Hz: MAVProxy's fence module has read several
        console.send("status SYS_STATUS")
        status = console.expect(r"SYS_STATUS \{.*onboard_control_sensors_health : (\d+)", 5)
    finally:
        transcript = console.close()
        proc.kill()
        stop_vehicle(proc)
    (tmp_path / "mavproxy.txt").write_text(transcript)
    assert int(status.group(1)) & 0x100000, status.group(0)  # MAV_SYS_STATUS_GEOFENCE healthy
    assert "fence breach" not in transcript, transcript
    assert "fence present" not in transcript and "fence enabled" not in transcript  # no fence claimed
