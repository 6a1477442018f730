"""The simulator over real loopback sockets: a pymavlink client plays the autopilot. The plant must
be `core.dynamics` exactly (up to the wire's quantisation), lockstep must step once per actuator
message, and bad input must be counted, never fatal. Every wait is bounded."""

import contextlib
import math
import socket
import struct
import threading
import time

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.generator.mavcrc import x25crc

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import ParamBatch
from quadpilot.core.start import sample_start_states
from quadpilot.link import wire
from quadpilot.link.transport import new_codec
from quadpilot.simulator import (
    DEFAULT_WIND_DRAG,
    TIME_ORIGIN_US,
    Plant,
    SimConfig,
    Simulator,
    SimulatorError,
    UsageError,
    build_sim_parser,
    config_from_args,
    main_sim_only,
    sensors,
)

HOME = wire.Home()
G = 9.81
DT_US = 10_000
TILTED = (0.3, -0.2, 2.1, 0.2, -0.1, 0.05, 0.15, -0.1, 1.0, 0.3, -0.2, 0.1)
LEVEL = (0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def config(**kw) -> SimConfig:
    kw = {"listen": "tcp:127.0.0.1:0", "episodes": 1, "lockstep_timeout_s": 2.0, **kw}
    return SimConfig(**kw)


@contextlib.contextmanager
def serving(cfg: SimConfig):
    """The simulator in a thread on a free port; yields (sim, port, result) and always stops it."""
    sim = Simulator(cfg)
    port = sim.bind().port
    result: dict = {}

    def run():
        try:
            result["stats"] = sim.serve()
        except BaseException as e:  # surfaced by the test, not lost in the thread
            result["error"] = e

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield sim, port, result
    finally:
        sim.stop()
        thread.join(5.0)
        assert not thread.is_alive(), "simulator did not stop"
        assert "error" not in result, result.get("error")


def finish(result: dict, timeout: float = 5.0) -> object:
    """Wait for serve() to return (its episodes are done); returns the stats."""
    deadline = time.monotonic() + timeout
    while "stats" not in result and "error" not in result:
        assert time.monotonic() < deadline, "serve() did not return"
        time.sleep(0.01)
    assert "error" not in result, result["error"]
    return result["stats"]


def connect(port: int, proto: str = "tcp"):
    c = mavutil.mavlink_connection(f"{proto}:127.0.0.1:{port}", source_system=255, source_component=190)
    # pymavlink's own connection (a PX4-like peer), given a MAVLink 2 codec from the first byte
    c.mav = new_codec(c, 255, 190)
    c.WIRE_PROTOCOL_VERSION, c.first_byte = "2.0", False
    if proto == "tcp":  # an autopilot announces itself first: a PX4-API simulator waits for it (UDP tests send it)
        c.mav.heartbeat_send(2, 12, 0, 0, 3)  # MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, MAV_STATE_STANDBY
    return c


def read_step(c, timeout: float = 2.0) -> list:
    """The messages of one simulation step: everything up to and including HIL_SENSOR."""
    msgs, deadline = [], time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"no HIL_SENSOR within {timeout} s (got {[m.get_type() for m in msgs]})"
        m = c.recv_match(blocking=True, timeout=left)
        if m is None:
            continue
        msgs.append(m)
        if m.get_type() == "HIL_SENSOR":
            return msgs


def by_type(msgs: list) -> dict:
    return {m.get_type(): m for m in msgs}


def send(c, motors, armed: bool = True) -> None:
    c.mav.hil_actuator_controls_send(**wire.actuator_controls_fields(np.asarray(motors, float), 0, armed, True))


def on_the_wire(x) -> np.ndarray:
    """What a float command becomes in HIL_ACTUATOR_CONTROLS (float32)."""
    return np.asarray(x, np.float32).astype(np.float64)


def assert_state_close(decoded: np.ndarray, truth: np.ndarray) -> None:
    """Equal within the wire's quantisation (see link.wire)."""
    assert np.all(np.abs(decoded[0:3] - truth[0:3]) <= np.array(HOME.position_quantum_m) / 2 + 1e-9)
    assert np.all(np.abs(decoded[3:6] - truth[3:6]) <= 0.005 + 1e-9)  # cm/s integers
    np.testing.assert_allclose(euler_to_rotmat(*decoded[6:9]), euler_to_rotmat(*truth[6:9]), atol=1e-6)
    np.testing.assert_allclose(decoded[9:12], truth[9:12], rtol=1e-6, atol=1e-6)


class Reference:
    """The same vehicle stepped in-process with core.dynamics."""

    def __init__(self, cfg: SimConfig) -> None:
        v = cfg.vehicle_params
        self.params = ParamBatch.from_preset(v, 1)
        self.state = np.array(cfg.initial_state, float)[None]
        self.rotor = np.full((1, 4), v.hover_command)
        self.u_hover = v.hover_command

    def step(self, command) -> np.ndarray:
        self.state, self.rotor = dynamics.step(self.state, self.rotor, np.asarray(command)[None], self.params, 0.01)
        return self.state[0]


def ned_from_frd(msg_q, v_frd) -> np.ndarray:
    return wire.quaternion_to_rotmat(msg_q) @ np.asarray(v_frd, float)


# --- the plant over the wire --------------------------------------------------------------------


def test_first_messages_carry_the_initial_state_and_consistent_sensors():
    cfg = config(initial_state=TILTED)
    with serving(cfg) as (_, port, _r):
        c = connect(port)
        msgs = read_step(c)
        c.close()
    assert [m.get_type() for m in msgs] == ["HIL_GPS", "HIL_STATE_QUATERNION", "HIL_SENSOR"]
    m = by_type(msgs)
    truth = np.array(TILTED)
    assert_state_close(wire.state_from_hil_state_quaternion(m["HIL_STATE_QUATERNION"], HOME), truth)
    assert {x.time_usec for x in msgs} == {TIME_ORIGIN_US}
    s = m["HIL_SENSOR"]
    q = m["HIL_STATE_QUATERNION"].attitude_quaternion
    np.testing.assert_allclose(wire.gyro_from_hil_sensor(s), truth[9:12], rtol=1e-6)
    # the magnetometer is the Earth field seen from the body: rotated back, it is the NED field
    np.testing.assert_allclose(ned_from_frd(q, [s.xmag, s.ymag, s.zmag]), sensors.MAG_NED_GAUSS, atol=1e-6)
    # rotors start at hover speed: the accelerometer feels m·g of thrust along body up
    np.testing.assert_allclose([s.xacc, s.yacc, s.zacc], [0.0, 0.0, -G], atol=1e-5)
    assert s.abs_pressure == pytest.approx(sensors.isa_pressure_hpa(HOME.alt_m + truth[2]), rel=1e-6)
    assert s.pressure_alt == pytest.approx(HOME.alt_m + truth[2])
    gps = m["HIL_GPS"]
    np.testing.assert_allclose(wire.geodetic_to_local(gps.lat, gps.lon, gps.alt, HOME), truth[0:3], atol=0.006)


def test_lockstep_flight_matches_core_dynamics_step_for_step():
    cfg = config(initial_state=TILTED)
    ref = Reference(cfg)
    # hover trim with a small per-motor pattern, so a motor-order mix-up would show
    command = on_the_wire(ref.u_hover * (1.0 + 0.005 * np.array([1.0, -1.0, 0.5, -0.5])))
    n_steps, gps_count, times = 60, 1, []
    with serving(cfg) as (_, port, result):
        c = connect(port)
        read_step(c)
        for _ in range(n_steps):
            send(c, command)
            msgs = read_step(c)
            m = by_type(msgs)
            gps_count += "HIL_GPS" in m
            times.append(m["HIL_SENSOR"].time_usec)
            assert_state_close(wire.state_from_hil_state_quaternion(m["HIL_STATE_QUATERNION"], HOME), ref.step(command))
        c.close()
        stats = finish(result)
    assert np.diff([TIME_ORIGIN_US, *times]).tolist() == [DT_US] * n_steps
    assert gps_count == n_steps // cfg.gps_every + 1  # steps 0, 10, …, 60
    (rec,) = stats.records
    assert (rec.steps, rec.end_reason, rec.crashed) == (n_steps, "peer_closed", False)
    np.testing.assert_array_equal(rec.final_state, ref.state[0])  # the same code: bit for bit


def test_an_impulse_jumps_the_velocity_east_once_at_its_step():
    """--impulse 1.5@0.2: after the plant's 20th step the velocity is 1.5 m/s more towards east than
    core.dynamics' (and stays so, as momentum), and nothing else differs at that step."""
    cfg = config(initial_state=LEVEL, impulse=(1.5, 0.2))
    ref = Reference(cfg)
    command = on_the_wire(np.full(4, ref.u_hover))
    with serving(cfg) as (_, port, result):
        c = connect(port)
        read_step(c)
        for n in range(1, 31):
            send(c, command)
            got = wire.state_from_hil_state_quaternion(by_type(read_step(c))["HIL_STATE_QUATERNION"], HOME)
            truth = ref.step(command)
            if n == 20:
                truth = ref.state[0] = truth + np.eye(12)[3] * 1.5
            assert_state_close(got, truth)
        c.close()
        finish(result)
    assert ref.state[0][3] == pytest.approx(1.5, abs=1e-6)  # the hit carries on: nothing slows it
    # a hit at T = 0 lands after the first step (the start state is sent before any step)
    cfg = config(initial_state=LEVEL, impulse=(-0.5, 0.0))
    with serving(cfg) as (_, port, result):
        c = connect(port)
        read_step(c)
        send(c, command)
        got = wire.state_from_hil_state_quaternion(by_type(read_step(c))["HIL_STATE_QUATERNION"], HOME)
        c.close()
        finish(result)
    assert got[3] == pytest.approx(-0.5, abs=0.01)
    with pytest.raises(ValueError, match="impulse must be"):
        config(impulse=(25.0, 1.0))
    with pytest.raises(ValueError, match="impulse must be"):
        config(impulse=(1.0, -1.0))


def test_free_fall_when_disarmed():
    cfg = config(initial_state=(0, 0, 10, 0, 0, 0, 0, 0, 0, 0, 0, 0), target=(0, 0, 10))
    with serving(cfg) as (_, port, _r):
        c = connect(port)
        read_step(c)
        for n in range(1, 31):
            send(c, [0.9, 0.9, 0.9, 0.9], armed=False)  # disarmed: whatever it asks, motors stay off
            m = by_type(read_step(c))
            s = wire.state_from_hil_state_quaternion(m["HIL_STATE_QUATERNION"], HOME)
            t = n * 0.01
            assert s[5] == pytest.approx(-G * t, abs=0.0051)
            assert s[2] == pytest.approx(10.0 - 0.5 * G * t * t, abs=0.0006)
            acc = m["HIL_SENSOR"]
            assert max(abs(acc.xacc), abs(acc.yacc), abs(acc.zacc)) < 1e-9  # a falling accelerometer reads 0
        c.close()


def test_lockstep_advances_exactly_one_step_per_actuator_message():
    cfg = config(initial_state=LEVEL)
    hover = on_the_wire(cfg.vehicle_params.hover_command)
    with serving(cfg) as (_, port, result):
        c = connect(port)
        assert read_step(c)[-1].time_usec == TIME_ORIGIN_US
        assert c.recv_match(blocking=True, timeout=0.2) is None  # nothing moves without a command
        for burst in (1, 3):
            for _ in range(burst):
                send(c, [hover] * 4)
            stamps = [read_step(c)[-1].time_usec for _ in range(burst)]
            assert c.recv_match(blocking=True, timeout=0.1) is None  # and no step more than asked
            assert (
                np.diff([TIME_ORIGIN_US if burst == 1 else TIME_ORIGIN_US + DT_US, *stamps]).tolist() == [DT_US] * burst
            )
        c.close()
        assert finish(result).steps == 4


def test_start_states_are_drawn_per_episode_from_the_seed():
    cfg = config(episodes=2, seed=7)
    seen = []
    with serving(cfg) as (_, port, result):
        for _ in range(2):
            c = connect(port)
            seen.append(wire.state_from_hil_state_quaternion(by_type(read_step(c))["HIL_STATE_QUATERNION"], HOME))
            c.close()
        stats = finish(result)
    for k, decoded in enumerate(seen):
        expected = sample_start_states(np.random.default_rng([7, k]), np.array([[0.0, 0.0, 2.0]]), 1.0, 0.5, 20.0)[0]
        assert_state_close(decoded, expected)
        np.testing.assert_array_equal(stats.records[k].initial_state, expected)
    assert stats.episodes == 2 and [r.end_reason for r in stats.records] == ["peer_closed"] * 2


# --- bad input ---------------------------------------------------------------------------------


def _unknown_id_packet(msg_id: int = 42424) -> bytes:
    payload = b"\x01\x02\x03"
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 7, 1, 1, msg_id & 0xFFFF, msg_id >> 16)
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([0]))
    return header + payload + struct.pack("<H", crc.crc)


def test_garbage_bad_crc_unknown_ids_and_bad_commands_are_dropped_and_counted():
    cfg = config(initial_state=LEVEL)
    ref = Reference(cfg)
    good = on_the_wire(ref.u_hover * np.array([1.01, 0.99, 1.0, 1.0]))
    packer = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    bad_crc = bytearray(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(packer))
    bad_crc[-1] ^= 0xFF
    garbage = b"\x00this is not mavlink\x01"
    with serving(cfg) as (sim, port, result):
        c = connect(port)
        read_step(c)
        c.write(garbage)
        c.write(bytes(bad_crc))
        c.write(_unknown_id_packet())
        c.mav.heartbeat_send(6, 8, 0, 0, 0)
        send(c, good)
        assert_state_close(
            wire.state_from_hil_state_quaternion(by_type(read_step(c))["HIL_STATE_QUATERNION"], HOME), ref.step(good)
        )
        # (the simulator now waits for the next command: its counters are settled)
        # (pymavlink reports stray bytes as BAD_DATA runs of one or more bytes)
        assert sim.stats.dropped == {
            "garbage": sim.stats.dropped.get("garbage", 0),
            "bad_crc": 1,
            "unknown_message_id": 1,
        }
        assert 1 <= sim.stats.dropped["garbage"] <= len(garbage)
        assert sim.stats.heartbeats == 2  # the one connect() sends first, and this one
        # bad values while armed: the packet is dropped, the motors keep the previous command, and
        # the step still happens (the peer waits for its next HIL_SENSOR)
        for bad in (math.nan, math.inf, 1.5, -0.1):
            c.mav.hil_actuator_controls_send(0, [0.5, bad, 0.5, 0.5] + [0.0] * 12, wire.ARMED, wire.LOCKSTEP)
            decoded = wire.state_from_hil_state_quaternion(by_type(read_step(c))["HIL_STATE_QUATERNION"], HOME)
            assert_state_close(decoded, ref.step(good))
        # a burst of random bytes, then zeros to flush any frame they opened: still alive
        c.write(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes() + bytes(300))
        send(c, good)
        assert_state_close(
            wire.state_from_hil_state_quaternion(by_type(read_step(c))["HIL_STATE_QUATERNION"], HOME), ref.step(good)
        )
        c.close()
        stats = finish(result)
    d = stats.dropped
    assert d["non_finite_control"] == 2 and d["out_of_range_control"] == 2
    assert d["bad_crc"] + d.get("bad_data", 0) > 1 and stats.steps == 6  # the random burst was dropped too
    assert stats.records[0].dropped == d and stats.records[0].end_reason == "peer_closed"


def test_a_taken_port_is_a_clear_error():
    for kind, proto in ((socket.SOCK_STREAM, "tcp"), (socket.SOCK_DGRAM, "udp")):
        with socket.socket(socket.AF_INET, kind) as other:
            other.bind(("127.0.0.1", 0))
            if kind == socket.SOCK_STREAM:
                other.listen(1)
            port = other.getsockname()[1]
            sim = Simulator(config(listen=f"{proto}:127.0.0.1:{port}"))
            with pytest.raises(
                SimulatorError, match=rf"cannot listen on {proto}:127.0.0.1:{port}: address already in use"
            ):
                sim.serve()


def test_lockstep_never_waits_for_ever():
    cfg = config(initial_state=LEVEL, lockstep_timeout_s=0.3)
    with serving(cfg) as (_, port, result):
        c = connect(port)
        read_step(c)
        t0 = time.monotonic()
        stats = finish(result)
        waited = time.monotonic() - t0
        c.port.setblocking(True)
        c.port.settimeout(2.0)
        assert c.port.recv(100) == b""  # the simulator hung up
        c.port.close()
    assert 0.25 <= waited < 2.0
    (rec,) = stats.records
    assert (rec.end_reason, rec.steps) == ("lockstep_timeout", 0)


def test_realtime_holds_the_command_then_cuts_the_motors_after_the_esc_timeout():
    cfg = config(initial_state=LEVEL, lockstep=False, esc_timeout_s=0.1, max_steps=50)
    hover = on_the_wire(cfg.vehicle_params.hover_command)
    accel_z = {}
    t0 = time.monotonic()
    with serving(cfg) as (_, port, result):
        c = connect(port)
        while True:
            s = read_step(c)[-1]
            n = (s.time_usec - TIME_ORIGIN_US) // DT_US
            accel_z[n] = s.zacc
            if n < 10:
                send(c, [hover] * 4)  # then fall silent
            if n == cfg.max_steps:
                break
        stats = finish(result)
        c.close()
    wall = time.monotonic() - t0
    assert stats.esc_timeouts == 1 and stats.records[0].esc_timeouts == 1
    assert stats.records[0].end_reason == "max_steps"
    assert all(accel_z[n] == pytest.approx(-G, abs=1e-4) for n in range(0, 10))  # hover thrust held
    assert all(abs(accel_z[n]) < 1e-9 for n in range(30, 51))  # motors cut: free fall
    assert 0.45 <= wall < 3.0  # 50 steps of 10 ms on the host clock


def test_udp_listen_pins_the_first_peer():
    cfg = config(listen="udp:127.0.0.1:0", initial_state=LEVEL, lockstep_timeout_s=0.3)
    hover = on_the_wire(cfg.vehicle_params.hover_command)
    with serving(cfg) as (_, port, result):
        c = connect(port, "udpout")
        c.mav.heartbeat_send(6, 8, 0, 0, 0)  # a UDP peer announces itself with its first message
        assert read_step(c)[-1].time_usec == TIME_ORIGIN_US
        intruder = connect(port, "udpout")
        send(intruder, [1.0] * 4)  # not the pinned peer: ignored, no step
        assert c.recv_match(blocking=True, timeout=0.1) is None
        send(c, [hover] * 4)
        assert read_step(c)[-1].time_usec == TIME_ORIGIN_US + DT_US
        stats = finish(result)  # then silence: the lockstep timeout ends the episode
        c.close()
        intruder.close()
    assert stats.heartbeats == 1 and stats.steps == 1 and stats.records[0].end_reason == "lockstep_timeout"
    assert stats.dropped == stats.records[0].dropped == {"foreign_peer": 1}


def test_imu_noise_leaves_the_ground_truth_exact():
    cfg = config(initial_state=LEVEL, imu_noise=True)
    hover = on_the_wire(cfg.vehicle_params.hover_command)
    gyro = []
    with serving(cfg) as (_, port, _r):
        c = connect(port)
        for _ in range(40):
            m = by_type(read_step(c))
            gyro.append(wire.gyro_from_hil_sensor(m["HIL_SENSOR"]))
            assert m["HIL_STATE_QUATERNION"].rollspeed == 0.0
            send(c, [hover] * 4)
        c.close()
    std = float(np.std(gyro, axis=0).mean())  # over time, per axis: the white part (the bias is ~constant)
    assert 0.5 * cfg.gyro_noise_std < std < 2.0 * cfg.gyro_noise_std
    assert cfg.gyro_noise_std == pytest.approx(3.39e-3, rel=1e-2) and cfg.accel_noise_std == pytest.approx(0.04)


# --- plant and configuration without sockets ---------------------------------------------------


def test_wind_drags_the_vehicle_downwind():
    cfg = SimConfig(wind=(2.0, 0.0, 0.0))
    assert cfg.effective_drag == DEFAULT_WIND_DRAG and SimConfig().effective_drag == 0.0
    v = cfg.vehicle_params
    plant = Plant(v, 0.01, cfg.wind)
    plant.reset(np.array(LEVEL))
    for _ in range(100):
        plant.step(np.full(4, v.hover_command))
    expected = 2.0 * (1.0 - math.exp(-v.drag / v.mass * 1.0))  # first-order approach to the wind speed
    assert plant.state[3] == pytest.approx(expected, rel=1e-2)
    assert abs(plant.state[5]) < 1e-9 and abs(plant.state[4]) < 1e-12
    # the accelerometer feels the drag along body x (level, nose east)
    assert plant.specific_force_flu()[0] == pytest.approx(v.drag * (2.0 - plant.state[3]) / v.mass)


def test_isa_barometer():
    assert sensors.isa_pressure_hpa(0.0) == pytest.approx(1013.25)
    assert sensors.isa_pressure_hpa(1000.0) == pytest.approx(898.75, abs=0.05)  # ISA table
    assert sensors.isa_temperature_c(1000.0) == pytest.approx(8.5)


def test_config_checks_and_scales():
    with pytest.raises(ValueError, match="expected tcp:HOST:PORT or udp:HOST:PORT"):
        SimConfig(listen="serial:/dev/ttyUSB0")
    with pytest.raises(ValueError, match="wind must be three finite numbers"):
        SimConfig(wind=(1.0, 2.0))
    with pytest.raises(ValueError, match="initial_state must be 12 finite numbers"):
        SimConfig(initial_state=(0.0,) * 11)
    with pytest.raises(ValueError, match="unknown vehicle preset"):
        SimConfig(vehicle="jumbo")
    cfg = SimConfig(mass_scale=1.1, inertia_scale=0.9, motor_scale=0.95)
    v, base = cfg.vehicle_params, SimConfig().vehicle_params
    assert (v.mass, v.ixx, v.izz, v.k_f) == pytest.approx(
        (base.mass * 1.1, base.ixx * 0.9, base.izz * 0.9, base.k_f * 0.95)
    )


def test_sim_only_cli_rejects_bad_flags(capsys):
    assert main_sim_only(["--wind", "1,2"]) == 2
    assert "expected three comma-separated numbers" in capsys.readouterr().err
    assert main_sim_only(["--mass-scale", "-1"]) == 2
    assert "expected a finite number > 0" in capsys.readouterr().err
    assert main_sim_only(["--listen", "tcp:127.0.0.1"]) == 2
    assert "expected tcp:HOST:PORT" in capsys.readouterr().err


def test_sim_only_cli_serves_and_reports(capsys):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    rc: dict = {}
    argv = ["--sim-only", "--listen", f"tcp:127.0.0.1:{port}", "--episodes", "1", "--seed", "3"]
    thread = threading.Thread(target=lambda: rc.setdefault("code", main_sim_only(argv)), daemon=True)
    thread.start()
    deadline = time.monotonic() + 5.0
    while True:  # connect once the simulator listens, then hang up: an episode of 0 steps
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            break
        except ConnectionRefusedError:
            assert time.monotonic() < deadline
            time.sleep(0.02)
    thread.join(5.0)
    assert not thread.is_alive() and rc["code"] == 0
    out = capsys.readouterr().out
    assert f"listening on tcp:127.0.0.1:{port}" in out and "episode 0: 0 steps" in out and "peer_closed" in out
    with socket.socket() as other:  # and a taken port: exit code 1, one clear line
        other.bind(("127.0.0.1", 0))
        other.listen(1)
        assert main_sim_only(["--listen", f"tcp:127.0.0.1:{other.getsockname()[1]}"]) == 1
        assert "address already in use" in capsys.readouterr().err


def test_gusts_are_a_gauss_markov_wind_with_the_asked_spread_and_time_constant():
    from quadpilot.core.vehicle_file import get_preset
    from quadpilot.simulator import Plant

    vehicle = SimConfig(gust=1.5).vehicle_params
    assert vehicle.drag > 0  # gusts alone switch the default wind drag on
    plant = Plant(vehicle, 0.01, gust_std=1.5, gust_tau_s=0.5, rng=np.random.default_rng(3))
    plant.reset(np.r_[0.0, 0.0, 2.0, np.zeros(9)])
    hover = np.full(4, get_preset("seed").hover_command)
    g = []
    for _ in range(20_000):
        plant.step(hover)
        plant.state[:] = np.r_[0.0, 0.0, 2.0, np.zeros(9)]  # keep it in place: only the wind matters here
        g.append(plant.gust.copy())
    g = np.asarray(g)
    assert np.std(g, axis=0) == pytest.approx([1.5] * 3, rel=0.2)
    lag = round(0.5 / 0.01)  # correlation at one time constant is e^-1
    corr = np.mean([np.corrcoef(g[:-lag, i], g[lag:, i])[0, 1] for i in range(3)])
    assert corr == pytest.approx(np.exp(-1), abs=0.1)
    assert config_from_args(build_sim_parser().parse_args(["--gust", "2", "--init-tilt", "5"])).gust == 2.0
    with pytest.raises(UsageError):
        config_from_args(build_sim_parser().parse_args(["--gust", "-1"]))
