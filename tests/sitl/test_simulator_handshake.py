"""Our simulator as a PX4-API simulator behaves: nothing is stepped before the autopilot's HEARTBEAT
(in either MAVLink version), and what it sends comes from its own system id, not the autopilot's.
The autopilot here is a bare socket with pymavlink's codecs."""

import socket
import threading
import time

import pytest
from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.autopilot.node import NODE_COMPONENT_ID, NODE_SYSTEM_ID
from quadpilot.link import wire
from quadpilot.link.transport import SIM_COMPONENT_ID, SIM_SYSTEM_ID
from quadpilot.simulator import SimConfig, Simulator

pytestmark = pytest.mark.sitl


class Sink:
    def __init__(self):
        self.out = bytearray()

    def write(self, buf):
        self.out += buf


def serve(**kw):
    records = []
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, **kw), on_episode=records.append)
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    return sim, thread, records, socket.create_connection(("127.0.0.1", port))


def read(sock, seconds: float) -> list:
    parser, got = mavlink2.MAVLink(None), []
    sock.settimeout(0.05)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
        if not data:
            break
        got += parser.parse_buffer(data) or []
    return got


def test_our_simulator_steps_only_after_the_autopilots_heartbeat_and_sends_as_itself():
    sim, thread, records, sock = serve(max_steps=2, lockstep_timeout_s=2.0)
    out = Sink()
    autopilot = mavlink1.MAVLink(out, srcSystem=NODE_SYSTEM_ID, srcComponent=NODE_COMPONENT_ID)
    try:
        assert read(sock, 0.3) == []  # connected, silent: no step
        autopilot.hil_actuator_controls_send(0, [0.5] * 16, wire.ARMED, wire.LOCKSTEP)  # a command is no HEARTBEAT
        sock.sendall(out.out)
        out.out.clear()
        assert read(sock, 0.3) == []
        autopilot.heartbeat_send(2, 12, 0, 0, 3)  # MAVLink 1: the simulator reads both versions
        sock.sendall(out.out)
        out.out.clear()
        step0 = read(sock, 0.5)
        assert [m.get_type() for m in step0] == ["HIL_GPS", "HIL_STATE_QUATERNION", "HIL_SENSOR"]
        assert {(m.get_srcSystem(), m.get_srcComponent()) for m in step0} == {(SIM_SYSTEM_ID, SIM_COMPONENT_ID)}
        assert SIM_SYSTEM_ID != NODE_SYSTEM_ID
        for _ in range(2):
            autopilot.hil_actuator_controls_send(0, [0.5] * 16, wire.ARMED, wire.LOCKSTEP)
            sock.sendall(out.out)
            out.out.clear()
            assert read(sock, 0.5)[-1].get_type() == "HIL_SENSOR"
    finally:
        sock.close()
        thread.join(5)
        sim.stop()
    (record,) = records
    assert record.steps == 2 and record.end_reason == "max_steps"
    assert record.dropped == {"before_heartbeat": 1}


def test_no_heartbeat_no_episode():
    sim, thread, records, sock = serve(lockstep_timeout_s=0.3)
    try:
        assert read(sock, 1.0) == []  # the simulator gave up and hung up without a step
    finally:
        sock.close()
        thread.join(5)
        sim.stop()
    (record,) = records
    assert record.steps == 0 and record.end_reason == "no_heartbeat"
