"""MAVProxy (PyPI `MAVProxy`, its own console commands typed on its stdin) against
`quad-sitl models/hover/policy.onnx --realtime --start landed --gcs ...`: the parameter list, `param
show` and `param set`, the mode list, `arm throttle`, `takeoff 2.5`, then a take-off and a landing
through DO_SET_MODE. What each command did is read on the vehicle's side: the `--tlog` of every
message the node sent and received (its PARAM_VALUE and COMMAND_ACK answers, and the simulator's
HIL_STATE_QUATERNION, the true position) and the `--json` summary.

Two things MAVProxy 1.8.75 (with pymavlink 2.4.50) does to a PX4 vehicle, PX4's and ours alike:
- `mode NAME` sends nothing: MAVProxy's mode module passes pymavlink's `px4_map[NAME]` (a tuple of
  base mode, main mode, sub mode) to `mavutil.set_mode`, whose PX4 branch (`set_mode_px4`) unpacks
  only a string, so packing COMMAND_LONG fails ("required argument is not a float",
  MAVProxy/modules/mavproxy_mode.py `cmd_mode`, pymavlink/mavutil.py `set_mode_px4`). Its generic
  `long DO_SET_MODE BASE MAIN SUB` does reach the vehicle; that is what a MAVProxy user has.
- `takeoff ALT` sends NAV_TAKEOFF with param7 = ALT (MAVProxy/modules/mavproxy_cmdlong.py
  `cmd_takeoff`): ArduPilot reads it above home, PX4 above mean sea level
  (src/modules/navigator/takeoff.cpp `set_takeoff_position`), so to PX4 `takeoff 2.5` is an altitude
  far below the vehicle: PX4 does not climb ("Already higher than takeoff altitude"), and this vehicle
  refuses it with that text.

MAVProxy is found next to this interpreter (the dev extra installs it there) or at $MAVPROXY (a
`mavproxy.py` in another virtual environment); the test fails when neither exists."""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mavsdk_gcs import HOME, free_udp_port, policy_copy, start_vehicle, stop_vehicle
from pymavlink import mavutil

from quadpilot.autopilot import param_protocol as params
from quadpilot.link.frames import geodetic_to_local
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl
M = mavutil.mavlink
TAKEOFF_ALT = 3.0  # set with `param set`; the Takeoff mode climbs to it
ARRIVAL_M = 0.15
PX4_RAPTOR = SHIPPED_HOVER.parents[1] / "hover_px4_raptor_sih" / "policy.tar"


def mavproxy_path() -> str | None:
    found = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    return found or os.environ.get("MAVPROXY") or None


class Console:
    """MAVProxy's interactive console on pipes: commands written to its stdin, every line it prints
    kept and searchable as it arrives."""

    def __init__(self, exe: str, port: int, cwd: Path) -> None:
        cmd = [exe, f"--master=udpin:127.0.0.1:{port}", "--no-state"]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # lines as they are printed, not at exit
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=cwd, env=env
        )
        self.lines: list[str] = []
        self._mark = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def send(self, line: str) -> None:
        self._mark = len(self.lines)
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def expect(self, pattern: str, timeout: float) -> re.Match:
        """The first line printed since the last `send` (the vehicle's answers arrive in any order:
        a HEARTBEAT with the new mode may come before the COMMAND_ACK) that matches `pattern`."""
        deadline = time.monotonic() + timeout
        while True:
            for line in self.lines[self._mark :]:
                if m := re.search(pattern, line):
                    return m
            if time.monotonic() > deadline:
                raise AssertionError(f"MAVProxy printed no {pattern!r} within {timeout:g} s: {self.lines[-15:]}")
            time.sleep(0.05)

    def close(self) -> str:
        try:
            if self.proc.poll() is None:
                self.proc.stdin.write("exit\n")
                self.proc.stdin.flush()
            self.proc.wait(timeout=10)
        except (subprocess.TimeoutExpired, BrokenPipeError):
            self.proc.kill()
            self.proc.wait()
        return "\n".join(self.lines)


def read_tlog(path: Path) -> list:
    log = mavutil.mavlink_connection(str(path))
    got = []
    while (m := log.recv_match()) is not None:
        if m.get_type() != "BAD_DATA":
            got.append(m)
    return got


def ftp_header(m) -> tuple:
    """seq_number, session, opcode, size, req_opcode, burst_complete, offset of a FILE_TRANSFER_PROTOCOL."""
    seq, session, op, size, req, burst, _, offset = struct.unpack_from("<HBBBBBBI", bytes(m.payload))
    return seq, session, op, size, req, burst, offset


def test_mavproxy_sets_a_parameter_arms_takes_off_and_lands_the_vehicle(tmp_path):
    exe = mavproxy_path()
    if exe is None:
        pytest.fail('MAVProxy not found: the dev extra installs it (pip install -e ".[dev]"), or set $MAVPROXY')
    port = free_udp_port()
    out, tlog = tmp_path / "summary.json", tmp_path / "flight.tlog"
    proc = start_vehicle(policy_copy(tmp_path), port, out, duration_s=60, tlog=tlog)
    console = Console(exe, port, tmp_path)
    t0 = time.monotonic()
    seen = {}
    try:
        console.expect(r"Detected vehicle 1:1", 20)
        seen["detected_s"] = time.monotonic() - t0
        # MAVProxy asks for the parameters by MAVLink FTP first (@PARAM/param.pck), then, if that
        # fails, by PARAM_REQUEST_LIST
        got = console.expect(r"Received (\d+) parameters( \(ftp\))?", 30)
        seen["params"], seen["params_by"] = int(got.group(1)), "ftp" if got.group(2) else "param protocol"
        seen["params_s"] = time.monotonic() - t0
        # MAVProxy's `ftp put` of a policy.tar onto the card: checked; not flown by this vehicle,
        # which flies an ONNX policy (autopilot/policy_upload.py)
        console.send(f"ftp put {PX4_RAPTOR} /fs/microsd/raptor/policy.tar")
        seen["put"] = console.expect(r"policy\.tar checked: .*", 10).group(0)
        seen["put_loaded"] = console.expect(r"policy\.tar not loaded: .*", 10).group(0)
        console.send("param show MIS_TAKEOFF_ALT")
        seen["shown"] = float(console.expect(r"MIS_TAKEOFF_ALT\s+(\S+)", 5).group(1))
        console.send(f"param set MIS_TAKEOFF_ALT {TAKEOFF_ALT}")
        time.sleep(1.0)  # the vehicle's PARAM_VALUE answer updates MAVProxy's copy
        console.send("param show MIS_TAKEOFF_ALT")
        seen["shown_after_set"] = float(console.expect(r"MIS_TAKEOFF_ALT\s+(\S+)", 5).group(1))
        console.send("mode")
        seen["modes"] = console.expect(r"Available modes:\s+(.*)", 5).group(1).replace(" ", "").split(",")
        console.send("mode loiter")  # see the module docstring: fails inside MAVProxy, nothing is sent
        seen["mode_loiter"] = console.expect(r"ERROR in command|Got COMMAND_ACK: DO_SET_MODE", 5).group(0)
        console.send("arm throttle")
        console.expect(r"Got COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED", 5)
        console.send("takeoff 2.5")
        seen["takeoff_2_5"] = console.expect(r"Got COMMAND_ACK: NAV_TAKEOFF: (\w+)", 5).group(1)
        # PX4's Takeoff mode (main 4, sub 2; base mode CUSTOM_MODE_ENABLED | AUTO | GUIDED | STABILIZE,
        # pymavlink's px4_map["TAKEOFF"]): climbs to MIS_TAKEOFF_ALT, then Hold (MAVProxy: LOITER)
        console.send("long DO_SET_MODE 29 4 2")
        console.expect(r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED", 5)
        console.expect(r"Mode TAKEOFF", 5)
        console.expect(r"Mode LOITER", 20)
        seen["takeoff_s"] = time.monotonic() - t0
        time.sleep(1.0)
        console.send("long DO_SET_MODE 29 4 6")  # Land
        console.expect(r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED", 5)
        console.expect(r"Mode LAND", 5)
        console.expect(r"DISARMED", 30)
        seen["wall_s"] = time.monotonic() - t0
    finally:
        transcript = console.close()
        code, _, stderr = stop_vehicle(proc)
    print(json.dumps(seen, indent=1))
    (tmp_path / "mavproxy.txt").write_text(transcript)
    assert code == 0, stderr  # quad-sitl ended on its own: landed and disarmed after a flight

    # MAVProxy's side
    assert seen["params"] == len(params.PARAMS)
    assert seen["params_by"] == "ftp"  # @PARAM/param.pck, the table in one transfer
    assert seen["put_loaded"].endswith("not flying a RAPTOR policy"), seen["put_loaded"]
    assert seen["shown"] == 2.5 and seen["shown_after_set"] == TAKEOFF_ALT
    assert {"LOITER", "TAKEOFF", "MISSION", "RTL", "LAND", "POSCTL"} <= set(seen["modes"])
    assert seen["mode_loiter"] == "ERROR in command", "MAVProxy's `mode NAME` works for PX4 now: fly with it"
    assert seen["takeoff_2_5"] == "DENIED"

    # the vehicle's side
    got = read_tlog(tlog)
    sent = [m for m in got if m.get_srcSystem() == 1]  # the node (the simulator is 200, MAVProxy 255)
    acks = [(m.command, m.result) for m in sent if m.get_type() == "COMMAND_ACK"]
    assert (M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_RESULT_ACCEPTED) in acks
    assert (M.MAV_CMD_NAV_TAKEOFF, M.MAV_RESULT_DENIED) in acks
    assert acks.count((M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_ACCEPTED)) == 2, acks  # `mode loiter` sent none
    values = [m.param_value for m in sent if m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT"]
    assert values and values[-1] == TAKEOFF_ALT, values  # (2.5 before: MAVProxy read it in the file)
    asked = [m for m in got if m.get_srcSystem() == 255 and m.get_type() == "PARAM_REQUEST_LIST"]
    assert not asked, "MAVProxy fell back to PARAM_REQUEST_LIST: the parameter file did not reach it"
    texts = [m.text for m in sent if m.get_type() == "STATUSTEXT"]
    assert any(t.startswith("Takeoff denied: already higher") for t in texts), texts
    truth = np.array(
        [
            geodetic_to_local(m.lat, m.lon, m.alt, HOME)
            for m in got
            if m.get_type() == "HIL_STATE_QUATERNION" and m.get_srcSystem() == 200
        ]
    )
    top = truth[np.argmax(truth[:, 2])]
    seen["top_m"], seen["landed_at_m"] = top.tolist(), truth[-1].tolist()
    print(seen["top_m"], seen["landed_at_m"])
    assert abs(top[2] - TAKEOFF_ALT) <= ARRIVAL_M  # the Takeoff mode climbed to the value MAVProxy set
    assert np.linalg.norm(truth[-1] - truth[0]) <= ARRIVAL_M  # and landed where it took off
    (c,) = json.loads(out.read_text())["commanded"]
    print(c)
    assert not c["armed"] and c["flown"] and c["landed_state"] == "ON_GROUND", c
    # all MAVProxy sent was understood but REQUEST_DATA_STREAM (MAVLink 1 stream rates, which PX4
    # ignores too)
    assert c["gcs_dropped"].keys() <= {"unexpected_request_data_stream"}, c
    # every MAVLink FTP request MAVProxy sent (the parameter file, then the `ftp put`) was answered at
    # once: each has its answer (sequence number + 1, the request's opcode), and none was sent again
    # (MAVProxy repeats a request only when no answer came within its retry time, at least 1 s, and
    # gives up on the parameter file after 10 repeats: the 10 s MAVProxy waited before its
    # parameters when the vehicle was silent)
    ftp = [m for m in got if m.get_type() == "FILE_TRANSFER_PROTOCOL"]
    requests = [ftp_header(m) for m in ftp if m.get_srcSystem() == 255]
    answers = {(h[0], h[4]) for h in (ftp_header(m) for m in ftp if m.get_srcSystem() == 1)}
    print(f"{len(requests)} FTP requests, {len(answers)} answered")
    assert requests, "MAVProxy sent no MAVLink FTP request: it no longer asks for the parameter file"
    assert all(((seq + 1) & 0xFFFF, op) in answers for seq, _, op, *_ in requests), (requests, answers)
    # (a request repeated: the same session, opcode and offset again; sequence numbers wrap at 256)
    assert len({(h[1], h[2], h[6]) for h in requests}) == len(requests), requests
    assert not [line for line in transcript.splitlines() if "FTP: request timed out" in line]
