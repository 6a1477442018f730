"""The node with a commander (`NodeConfig(command=True)`) against our simulator in this process, a
pymavlink ground station on the other side of its UDP socket: a lockstep flight from the ground (the
commander on simulated time), motors off while disarmed or idle, and the node's own failsafe on
simulator link loss reported to the ground station as PX4 would."""

import contextlib
import math
import socket
import struct
import threading
import time

import numpy as np
import pytest
from pymavlink import mavutil

from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl
M = mavutil.mavlink
NAN = math.nan


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Gcs:
    """A pymavlink ground station (system 255, component 190) listening on a UDP port, as MAVSDK and
    QGroundControl do, that sends a heartbeat with everything it sends."""

    def __init__(self) -> None:
        self.port = free_udp_port()
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=255, source_component=190)
        self.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.got: list = []

    def recv(self, timeout: float = 0.2):
        m = self.conn.recv_match(blocking=True, timeout=timeout)
        if m is not None and m.get_type() != "BAD_DATA":
            self.got.append(m)
            return m
        return None

    def beat(self) -> None:
        self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)

    def until(self, ok, timeout: float, what: str):
        """Keep the link alive and read until a message satisfies `ok`."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.beat()
            m = self.recv(0.02)
            if m is not None and ok(m):
                return m
        raise AssertionError(f"no {what} within {timeout:g} s")

    def command(self, cmd: int, *params: float) -> int:
        p = [*params, *[0.0] * (7 - len(params))]
        self.conn.mav.command_long_send(1, 1, cmd, 0, *p)
        ack = self.until(lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd, 5, f"ack of {cmd}")
        return ack.result

    def set_param(self, name: str, value: float, kind: int) -> None:
        wire = value if kind == M.MAV_PARAM_TYPE_REAL32 else struct.unpack("<f", struct.pack("<i", int(value)))[0]
        self.conn.mav.param_set_send(1, 1, name.encode(), wire, kind)
        self.until(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, 5, f"PARAM_VALUE {name}")

    def close(self) -> None:
        self.conn.close()


def vehicle_heartbeats(msgs) -> list:
    return [m for m in msgs if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1]


@contextlib.contextmanager
def landed_flight(duration_s: float):
    """Our simulator (landed start) and a commanded node flying the shipped hover policy, each in a
    thread, and a ground station: yields (ground station, simulator, the node's thread, the dict
    that gets the node's log); on the way out stops the simulator and closes the ground station."""
    gcs = Gcs()
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, start="landed"))
    port = sim.bind().port
    sim_thread = threading.Thread(target=sim.serve, daemon=True)
    sim_thread.start()
    cfg = NodeConfig(
        connect=f"tcp:127.0.0.1:{port}",
        duration_s=duration_s,
        gcs=f"udp:127.0.0.1:{gcs.port}",
        command=True,
        start="landed",
    )
    result: dict = {}
    node = threading.Thread(target=lambda: result.update(log=Node(cfg).fly(SafetyMonitor(load_policy(SHIPPED_HOVER)))))
    node.start()
    try:
        yield gcs, sim, node, result
    finally:
        sim.stop()
        sim_thread.join(5)
        node.join(5)
        gcs.close()


def take_off(gcs: Gcs) -> None:
    """Wait for the vehicle, give the ground station time to react, arm and take off."""
    gcs.until(lambda m: m.get_type() == "HEARTBEAT" and m.autopilot == M.MAV_AUTOPILOT_PX4, 10, "vehicle")
    # lockstep runs many times faster than the wall clock: give the ground station time to react
    gcs.set_param("COM_DISARM_PRFLT", 60.0, M.MAV_PARAM_TYPE_REAL32)
    gcs.set_param("COM_DL_LOSS_T", 300, M.MAV_PARAM_TYPE_INT32)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, NAN) == M.MAV_RESULT_ACCEPTED


def test_a_lockstep_flight_from_the_ground_takes_off_lands_and_disarms_with_motors_off_on_the_ground():
    with landed_flight(120.0) as (gcs, sim, node, result):
        take_off(gcs)
        gcs.until(lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.relative_alt > 2400, 30, "2.4 m")
        gcs.until(
            lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and m.custom_mode == 3 << 24 | 4 << 16,
            30,
            "Hold",
        )
        assert gcs.command(M.MAV_CMD_NAV_LAND, NAN, NAN, NAN, NAN, NAN, NAN, NAN) == M.MAV_RESULT_ACCEPTED
        gcs.until(
            lambda m: (
                m.get_type() == "HEARTBEAT"
                and m.get_srcSystem() == 1
                and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
            ),
            30,
            "disarm",
        )
        node.join(30)
        while gcs.recv(0.1) is not None:
            pass
    log = result["log"]
    t, z = np.asarray(log.t), np.asarray(log.states)[:, 2]
    cmds, sources = np.asarray(log.commands), np.asarray(log.sources)
    assert log.failsafe is None and log.t[-1] < 100  # ended by the disarm, not the cap
    assert log.commander["landed_state"] == "ON_GROUND" and not log.commander["armed"] and log.commander["flown"]
    texts = [text for _, text in log.events]
    for event in ("Armed by external command", "Takeoff detected", "Landing detected", "Disarmed by landing"):
        assert event in texts, texts
    armed_at = next(t for t, text in log.events if text == "Armed by external command")
    disarmed_at = next(t for t, text in log.events if text == "Disarmed by landing")
    off = (t < armed_at) | (t > disarmed_at)
    assert off.sum() > 50 and np.all(cmds[off] == 0) and set(sources[off]) == {"idle"}  # motors off while disarmed
    assert np.all(z[t < armed_at] == 0.0)  # and the simulator's ground holds the vehicle
    assert 2.35 <= z.max() <= 2.65 and z[-1] == 0.0
    assert set(sources[~off]) <= {"policy", "idle"}  # never the fallback
    record = sim.stats.records[0]
    assert not record.crashed and record.final_state[2] == 0.0
    # the commander's telemetry replaced the GroundStation's own: only PX4 heartbeats from the vehicle
    assert {m.autopilot for m in vehicle_heartbeats(gcs.got)} == {M.MAV_AUTOPILOT_PX4}


def test_the_node_failsafe_on_simulator_link_loss_reaches_the_ground_station_as_disarmed_and_critical():
    gcs = Gcs()
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, lockstep=False))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    threading.Timer(1.5, sim.stop).start()  # the simulator goes away mid-flight
    try:
        cfg = NodeConfig(
            connect=f"tcp:127.0.0.1:{port}",
            duration_s=5.0,
            lockstep=False,
            gcs=f"udp:127.0.0.1:{gcs.port}",
            command=True,
        )
        log = Node(cfg).fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")))
        while gcs.recv(0.2) is not None:
            pass
    finally:
        sim.stop()
        thread.join(5)
        gcs.close()
    assert log.failsafe is not None
    texts = [m.text for m in gcs.got if m.get_type() == "STATUSTEXT"]
    assert any(t.startswith("failsafe:") for t in texts), texts
    beats = vehicle_heartbeats(gcs.got)
    assert {m.autopilot for m in beats} == {M.MAV_AUTOPILOT_PX4}
    assert beats[0].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED  # started in the air: armed, holding
    assert not beats[-1].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and beats[-1].system_status == M.MAV_STATE_CRITICAL
    assert log.commander["flown"] and not log.commander["armed"]


@pytest.mark.parametrize(("heading_ned", "yaw_enu_deg"), [(0.0, 90.0), (-math.pi / 2, 180.0)], ids=["north", "west"])
def test_a_goto_with_a_yaw_turns_the_vehicle_to_that_heading_and_holds_it(heading_ned, yaw_enu_deg):
    """DO_REPOSITION in place with param4 = 0 (north, MAVLink's heading, rad) or −π/2 (west) turns a
    vehicle that took off facing east (the landed start's heading) by 90° or 180°: more than the
    policy was trained to turn at once (30°), so the node gives it a heading at most 25° ahead and it
    turns steadily; it ends facing the new heading, holding still, where it was."""
    with landed_flight(40.0) as (gcs, _sim, node, result):
        take_off(gcs)
        gcs.until(
            lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and m.custom_mode == 3 << 24 | 4 << 16,
            30,
            "Hold",
        )
        int32_max = 2**31 - 1  # lat/lon "keep the current position" (MAVLink COMMAND_INT)
        gcs.conn.mav.command_int_send(
            1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, heading_ned,
            int32_max, int32_max, NAN,
        )  # fmt: skip
        ack = gcs.until(
            lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_REPOSITION, 5, "ack of the goto"
        )
        assert ack.result == M.MAV_RESULT_ACCEPTED
        node.join(60)
    log = result["log"]
    t, s = np.asarray(log.t), np.asarray(log.states)
    assert log.failsafe is None and set(np.asarray(log.sources)) <= {"policy", "idle"}
    yaw_enu = np.degrees(s[:, 8])
    flying = s[:, 2] > 2.0
    assert np.all(np.abs(yaw_enu[flying][:10]) < 10.0)  # it took off facing east (ENU yaw 0)
    last = t > t[-1] - 2.0  # the last 2 s: facing the new heading, still, where it took off
    off = (yaw_enu[last] - yaw_enu_deg + 180.0) % 360.0 - 180.0
    assert np.all(np.abs(off) < 10.0), yaw_enu[last]
    assert np.abs(s[last, 11]).mean() < 0.2
    assert np.linalg.norm(s[last, 0:2], axis=1).max() < 0.15 and np.all(np.abs(s[last, 2] - 2.5) < 0.15)
