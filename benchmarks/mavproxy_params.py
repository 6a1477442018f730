"""How long MAVProxy takes to have the vehicle's parameters, three ways, kept as data for
docs/ground_station.md:

    .venv/bin/python benchmarks/mavproxy_params.py docs/bench/mavproxy_params.json   # about 1 minute

`quad-sitl models/hover/policy.onnx --realtime --start landed --gcs udp:...` (a copy of the shipped
model) and MAVProxy 1.8.75 (`mavproxy.py --master=udpin:...`, next to this interpreter), with a UDP
relay between them that passes every datagram unchanged except MAVProxy's FILE_TRANSFER_PROTOCOL
requests:
- `served`: passed: the vehicle serves `@PARAM/param.pck` (autopilot/ftp_protocol.py);
- `missing`: the file name asked for is changed to `@PARAM/none.pck` (the message packed again with
  MAVProxy's ids and sequence number), so the vehicle answers NAK FileNotFound, as PX4 answers it;
- `dropped`: not passed on, so nothing answers them: the vehicle before it answered MAVLink FTP.
Each measures, on the host clock, from MAVProxy printing "Detected vehicle" to its "Received N
parameters", and lists MAVProxy's FTP requests (sequence number, session, opcode). Real time: the
figures depend on the machine's load, which is recorded with them.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import select
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

ROOT = Path(__file__).resolve().parents[1]
MODES = ("served", "missing", "dropped")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Relay(threading.Thread):
    """Vehicle ↔ MAVProxy on loopback; MAVProxy's FTP requests passed, renamed or dropped (`mode`)."""

    def __init__(self, mode: str, mavproxy_port: int) -> None:
        super().__init__(daemon=True)
        self.mode, self.to_gcs = mode, ("127.0.0.1", mavproxy_port)
        self.sock_vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the vehicle sends here
        self.sock_vehicle.bind(("127.0.0.1", 0))
        self.sock_gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # MAVProxy answers here
        self.sock_gcs.bind(("127.0.0.1", 0))
        self.port = self.sock_vehicle.getsockname()[1]
        self.vehicle = None
        self.ftp_requests: list = []  # [seq_number, session, opcode] of each of MAVProxy's FTP requests
        self.stop = False
        self._parse = mavlink2.MAVLink(None)
        self._parse.robust_parsing = True

    def _from_gcs(self, data: bytes) -> bytes:
        out = b""
        for m in self._parse.parse_buffer(data) or []:
            raw = bytes(m.get_msgbuf())
            if m.get_type() == "FILE_TRANSFER_PROTOCOL":
                self.ftp_requests.append(list(struct.unpack_from("<HBB", bytes(m.payload))))
                if self.mode == "dropped":
                    continue
                if self.mode == "missing":
                    payload = bytes(m.payload)
                    name = payload[12:].split(b"\0", 1)[0]
                    if name.startswith(b"@PARAM/"):
                        new = b"@PARAM/none.pck"
                        payload = payload[:4] + bytes([len(new)]) + payload[5:12] + new.ljust(239, b"\0")
                        enc = mavlink2.MAVLink(None, srcSystem=m.get_srcSystem(), srcComponent=m.get_srcComponent())
                        enc.seq = m.get_seq()
                        raw = bytes(
                            mavlink2.MAVLink_file_transfer_protocol_message(
                                m.target_network, m.target_system, m.target_component, list(payload)
                            ).pack(enc)
                        )
            out += raw
        return out

    def run(self) -> None:
        while not self.stop:
            ready, _, _ = select.select([self.sock_vehicle, self.sock_gcs], [], [], 0.05)
            for s in ready:
                data, addr = s.recvfrom(65536)
                if s is self.sock_vehicle:
                    self.vehicle = addr
                    self.sock_gcs.sendto(data, self.to_gcs)
                elif self.vehicle is not None:
                    data = self._from_gcs(data)
                    if data:
                        self.sock_vehicle.sendto(data, self.vehicle)


def measure(mode: str, tmp: Path) -> dict:
    mavproxy = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    if mavproxy is None:
        raise SystemExit("mavproxy.py not found next to this interpreter: the dev extra installs it")
    shutil.copytree(ROOT / "models" / "hover", tmp / mode / "hover")
    gcs_port = _free_port()
    relay = Relay(mode, gcs_port)
    relay.start()
    policy = tmp / mode / "hover" / "policy.onnx"
    cmd = [sys.executable, "-m", "quadpilot.sitl", str(policy), "--realtime", "--start", "landed", "--duration", "40"]
    vehicle = subprocess.Popen(
        [*cmd, "--gcs", f"udp:127.0.0.1:{relay.port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    gcs = subprocess.Popen(
        [mavproxy, f"--master=udpin:127.0.0.1:{gcs_port}", "--no-state"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp / mode,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    seen: dict = {"mode": mode}
    try:
        deadline = time.monotonic() + 40
        for line in gcs.stdout:
            now = time.monotonic()
            if "Detected vehicle 1:1" in line and "detected" not in seen:
                seen["detected"] = now
            if m := re.search(r"Received (\d+) parameters( \(ftp\))?", line):
                seen["params"], seen["by"] = int(m.group(1)), "ftp" if m.group(2) else "param protocol"
                seen["detect_to_params_s"] = now - seen.pop("detected")
                break
            if now > deadline:
                break
    finally:
        time.sleep(0.5)  # the last FTP requests (MAVProxy's TerminateSession) reach the relay
        seen["ftp_requests"] = relay.ftp_requests
        opens = [session for _, session, op in relay.ftp_requests if op == 4]  # OpenFileRO
        seen["opens_per_session"] = max((opens.count(s) for s in set(opens)), default=0)  # 1: never repeated
        seen["sessions"] = len(set(opens))  # MAVProxy may start the file transfer twice
        relay.stop = True
        for p in (gcs, vehicle):
            p.kill()
            p.wait()
    seen.pop("detected", None)
    return seen


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="the JSON to write, e.g. docs/bench/mavproxy_params.json")
    a = p.parse_args(argv)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as d:
        runs = {mode: measure(mode, Path(d)) for mode in MODES}
    result = {
        "what": "host seconds from MAVProxy's 'Detected vehicle' to its 'Received N parameters'",
        "made_by": "benchmarks/mavproxy_params.py",
        "runs": runs,
        "load_1min": {"before": load, "after": os.getloadavg()[0]},
    }
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
