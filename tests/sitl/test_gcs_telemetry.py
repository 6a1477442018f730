"""A ground station listening on UDP (as QGroundControl and MAVProxy do on 14550) watches a flight:
a plain pymavlink client reads the vehicle's attitude and position from the node's telemetry."""

import math
import socket
import threading

import numpy as np
import pytest
from pymavlink import mavutil

from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.link import wire
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl


def test_a_pymavlink_ground_station_reads_attitude_and_position_during_a_flight():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        gcs_port = s.getsockname()[1]
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    got: dict[str, list] = {}
    stop = threading.Event()

    # a lockstep flight can end before this thread is ever scheduled on a busy machine: the
    # datagrams wait in the socket (made large enough for all of them), and the reader drains it
    # until it has been quiet for 0.3 s after the flight ends
    gcs.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)

    def listen():
        while True:
            m = gcs.recv_match(blocking=True, timeout=0.3)
            if m is not None:
                got.setdefault(m.get_type(), []).append(m)
            elif stop.is_set():
                return

    reader = threading.Thread(target=listen, daemon=True)
    reader.start()
    try:
        node = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=3.0, gcs=f"udp:127.0.0.1:{gcs_port}"))
        log = node.fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")))
    finally:
        stop.set()
        reader.join(10)
        sim.stop()
        thread.join(5)
        gcs.close()
    for kind in ("HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "SYS_STATUS"):
        assert got.get(kind), f"no {kind} (got {sorted(got)})"
    assert len(got["ATTITUDE"]) == 300 // 4  # 25 Hz of simulated time over 3 s
    hb = got["HEARTBEAT"][0]
    assert hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR and hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    # the last telemetry sample is the state of its step, in NED/FRD
    states = {round(t * 1000): s for t, s in zip(log.t, log.states, strict=True)}
    att, pos = got["ATTITUDE"][-1], got["LOCAL_POSITION_NED"][-1]
    s = states[att.time_boot_ms]
    roll, pitch, yaw = wire.attitude_ned_frd(s)
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((roll, pitch, yaw), abs=1e-6)
    s = states[pos.time_boot_ms]
    assert (pos.x, pos.y, pos.z) == pytest.approx((s[1], s[0], -s[2]), abs=1e-5)
    g = got["GLOBAL_POSITION_INT"][-1]
    assert g.relative_alt == round(states[g.time_boot_ms][2] * 1000)
    assert abs(pos.z + 2.0) < 0.05  # hovering at 2 m: z = −2 m in NED
    assert math.isfinite(att.rollspeed) and np.isfinite([p.z for p in got["LOCAL_POSITION_NED"]]).all()


def test_the_ground_station_hears_the_failsafe():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        gcs_port = s.getsockname()[1]
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, lockstep=False))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    threading.Timer(0.5, sim.stop).start()  # the simulator goes away mid-flight
    try:
        node = Node(
            NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=5.0, lockstep=False, gcs=f"udp:127.0.0.1:{gcs_port}")
        )
        log = node.fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")))
        texts, states = [], []
        while (m := gcs.recv_match(blocking=True, timeout=0.2)) is not None:
            if m.get_type() == "STATUSTEXT":
                texts.append(m.text)
            elif m.get_type() == "HEARTBEAT":
                states.append(m.system_status)
    finally:
        sim.stop()
        thread.join(5)
        gcs.close()
    assert log.failsafe is not None
    assert any(t.startswith("failsafe:") for t in texts), texts
    assert states[-1] == mavutil.mavlink.MAV_STATE_CRITICAL
