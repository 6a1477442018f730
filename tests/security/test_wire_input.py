"""What arrives on the wire can neither end nor steer the autopilot node or the simulator.

Property tests (Hypothesis, derandomised) feed both sides arbitrary bytes and well-formed but
hostile MAVLink messages (every message type they handle, each field drawn from the full range of
its type, NaN and ±Inf included) through their real receive and dispatch paths: the node's `fly()`
against a scripted peer over loopback TCP, the simulator's episode loop on a loopback connection.
Nothing may escape the loop, and every motor command sent (node) or applied (simulator) must be
finite and within [0, 1]. A third property drives the simulator's physics, sensor and wire path
with arbitrary in-range command sequences for 100,000 steps: the state stays finite and pymavlink
packs every message. Then one regression test per attack that worked before.
"""

from __future__ import annotations

import functools
import math
import socket
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.autopilot.flight_log import episode_summary
from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.core.observation import HOVER_LAYOUT, build_observation
from quadpilot.link import transport, wire
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import TIME_ORIGIN_US, Plant, SimConfig, Simulator, sensors
from quadpilot.sitl import SHIPPED_HOVER

HOME = wire.Home()
HOVER_STATE = np.array([0.0, 0.0, 2.0] + [0.0] * 9)
STEP_US = 10_000
TIMES = [TIME_ORIGIN_US + k * STEP_US for k in range(6)]
"""A few coherent step times, so hostile states and sensors often belong to the same step."""
PROPERTY = settings(
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example],
)
VEHICLE = SimConfig().vehicle_params  # the simulator's default airframe, the shipped policy's
HOVER_CMD = VEHICLE.hover_command


@functools.cache
def policy():
    return load_policy(SHIPPED_HOVER, "numpy")


# --- hostile messages, built with pymavlink -------------------------------------------------------
_INT_RANGE = {
    "int8_t": (-(2**7), 2**7 - 1),
    "uint8_t": (0, 2**8 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
    "uint64_t": (0, 2**64 - 1),
}


def _any_value(kind: str, length: int):
    """Any value of a MAVLink field type: floats of the wire's width with NaN, ±Inf and extremes,
    integers over the type's whole range (its limits drawn often), char arrays as any bytes."""
    if kind == "char":
        return st.binary(max_size=length)
    if kind == "float":
        one = st.floats(width=32)
    elif kind == "double":
        one = st.floats()
    else:
        lo, hi = _INT_RANGE[kind]
        one = st.one_of(st.sampled_from(sorted({lo, hi, 0, min(hi, 1), max(lo, -1)})), st.integers(lo, hi))
    return st.lists(one, min_size=length, max_size=length) if length else one


def hostile(cls, nominal: dict, time_usec=None):
    """Messages of `cls`: the genuine one (`nominal`), or it with one field set to any value of its
    type, or with every field either genuine or any value; `time_usec`, if given, is the strategy
    for that field."""
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    anything = {
        name: _any_value(kind, lengths[name]) for name, kind in zip(cls.fieldnames, cls.fieldtypes, strict=True)
    }
    one_field = st.sampled_from(sorted(anything)).flatmap(lambda n: anything[n].map(lambda v: {**nominal, n: v}))
    every_field = st.fixed_dictionaries({n: st.one_of(st.just(nominal[n]), v) for n, v in anything.items()})
    fields = st.one_of(st.just(nominal), one_field, every_field)
    if time_usec is not None:
        fields = st.tuples(fields, time_usec).map(lambda a: {**a[0], "time_usec": a[1]})
    return fields.map(lambda f: cls(**f))


def _times():
    return st.one_of(st.sampled_from(TIMES), _any_value("uint64_t", 0))


def _state_msg(t=None):
    nominal = wire.hil_state_quaternion_fields(HOVER_STATE, HOME, TIMES[0])
    return hostile(mavlink2.MAVLink_hil_state_quaternion_message, nominal, _times() if t is None else t)


def _sensor_msg(t=None):
    z3 = np.zeros(3)
    nominal = wire.hil_sensor_fields(TIMES[0], z3, np.array([0.0, 0.0, 9.81]), z3, 955.0, 490.0)
    return hostile(mavlink2.MAVLink_hil_sensor_message, nominal, _times() if t is None else t)


def _odometry_msg(t=None):
    nominal = wire.odometry_fields(HOVER_STATE, TIMES[0])
    return hostile(mavlink2.MAVLink_odometry_message, nominal, _times() if t is None else t)


def _actuator_msg():
    nominal = wire.actuator_controls_fields(np.full(4, HOVER_CMD), TIMES[0], True, True)
    return hostile(mavlink2.MAVLink_hil_actuator_controls_message, nominal)


GPS = hostile(mavlink2.MAVLink_hil_gps_message, wire.hil_gps_fields(HOVER_STATE, HOME, TIMES[0]))
HEARTBEAT = hostile(
    mavlink2.MAVLink_heartbeat_message,
    {"type": 6, "autopilot": 8, "base_mode": 0, "custom_mode": 0, "system_status": 4, "mavlink_version": 3},
)
STATUSTEXT = hostile(mavlink2.MAVLink_statustext_message, {"severity": 6, "text": b"hello", "id": 0, "chunk_seq": 0})


def _step(t):
    """One simulator step as the node sees it: a state, maybe an estimate, and the sensor, one time."""
    return st.tuples(_state_msg(st.just(t)), st.lists(_odometry_msg(st.just(t)), max_size=1), _sensor_msg(st.just(t)))


_STEP = st.sampled_from(TIMES).flatmap(_step).map(lambda s: [s[0], *s[1], s[2]])
NODE_MESSAGES = st.one_of(
    _STEP,
    _STEP,
    st.one_of(_state_msg(), _sensor_msg(), _odometry_msg(), GPS, HEARTBEAT, STATUSTEXT, _actuator_msg()).map(
        lambda m: [m]
    ),
)
SIM_MESSAGES = st.one_of(_actuator_msg(), _actuator_msg(), HEARTBEAT, _state_msg(), STATUSTEXT).map(lambda m: [m])


def _pack(msgs) -> bytes:
    codec = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return b"".join(m.pack(codec) for m in msgs)


def _corrupt(frame: bytes, at: int, xor: int) -> bytes:
    b = bytearray(frame)
    b[at % len(b)] ^= xor or 0xFF
    return bytes(b)


def byte_stream(messages):
    """Arbitrary bytes; a stream of hostile frames; or such frames mixed with junk, bit flips and
    torn frames (which swallow what follows them, as on a real stream)."""
    frames = messages.map(_pack)
    mangled = st.one_of(
        st.binary(max_size=80),
        st.tuples(frames, st.integers(0, 400), st.integers(0, 255)).map(lambda a: _corrupt(*a)),
        st.tuples(frames, st.integers(1, 400)).map(lambda a: a[0][: a[1] % len(a[0])]),
    )
    return st.one_of(
        st.binary(max_size=4096),
        st.lists(frames, max_size=30).map(b"".join),
        st.lists(st.one_of(frames, frames, frames, mangled), max_size=30).map(b"".join),
    )


# --- harnesses -------------------------------------------------------------------------------
def parse(data: bytes) -> list:
    return transport.new_codec(None, 255, 190).parse_buffer(data) or []


def fly_against(data: bytes, gcs: bool = True, duration_s: float = 5.0):
    """Fly the node (its real `fly()`) against a peer on loopback TCP that sends `data` and hangs
    up; returns (log, what the node sent the peer, what it sent the ground station)."""
    srv = socket.create_server(("127.0.0.1", 0))
    gs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gs.bind(("127.0.0.1", 0))
    gs.setblocking(False)
    got = bytearray()

    def peer():
        conn, _ = srv.accept()
        with conn:
            conn.sendall(data)
            conn.shutdown(socket.SHUT_WR)
            conn.settimeout(5.0)
            while chunk := conn.recv(65536):
                got.extend(chunk)

    thread = threading.Thread(target=peer, daemon=True)
    thread.start()
    cfg = NodeConfig(
        connect=f"tcp:127.0.0.1:{srv.getsockname()[1]}",
        gcs=f"udp:127.0.0.1:{gs.getsockname()[1]}" if gcs else None,
        duration_s=duration_s,
        connect_timeout_s=5.0,
    )
    try:
        log = Node(cfg).fly(SafetyMonitor(policy()))
    finally:
        thread.join(5.0)
        srv.close()
    telemetry = []
    try:
        while True:
            telemetry += parse(gs.recv(65536))
    except BlockingIOError:
        pass
    finally:
        gs.close()
    assert not thread.is_alive()
    return log, parse(bytes(got)), telemetry


def assert_node_output_safe(log, sent, telemetry) -> None:
    cmds = np.asarray(log.commands, np.float64).reshape(-1, 4)
    assert np.all(np.isfinite(cmds)) and np.all((cmds >= 0.0) & (cmds <= 1.0))
    assert np.all(np.isfinite(np.asarray(log.states, np.float64)))
    answered = []
    for m in sent:
        assert m.get_type() != "BAD_DATA"
        if m.get_type() == "HIL_ACTUATOR_CONTROLS":
            assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in m.controls), m.controls
            if m.mode & wire.ARMED:
                answered.append(m.time_usec)
    assert len(answered) == len(set(answered)), "a step was answered twice"
    for m in telemetry:
        if m.get_type() in ("ATTITUDE", "LOCAL_POSITION_NED"):  # built from the state: finite floats only
            assert all(math.isfinite(getattr(m, f)) for f in m.get_fieldnames() if f != "time_boot_ms"), m


class Watched(Simulator):
    """The simulator, recording every command it applies to the plant."""

    def __init__(self, cfg: SimConfig) -> None:
        super().__init__(cfg)
        self.applied: list[np.ndarray] = []

    def _advance(self, link, plant, command, n, rng, ep):
        self.applied.append(np.array(command, np.float64))
        return super()._advance(link, plant, command, n, rng, ep)


def tcp_pair() -> tuple[socket.socket, socket.socket]:
    with socket.create_server(("127.0.0.1", 0)) as srv:
        client = socket.create_connection(srv.getsockname())
        server, _ = srv.accept()
    return server, client


def serve_bytes(data: bytes, lockstep: bool = True):
    """One simulator episode in-process on a loopback connection whose peer sends `data` and hangs
    up: (record, commands applied)."""
    sim = Watched(SimConfig(initial_state=tuple(HOVER_STATE), lockstep=lockstep))
    server, client = tcp_pair()
    try:
        client.sendall(data)
        client.shutdown(socket.SHUT_WR)
        link = transport.StreamLink(server, "tcp:test", transport.SIM_SYSTEM_ID, transport.SIM_COMPONENT_ID)
        record = sim._run_episode(link, 0)
    finally:
        server.close()
        client.close()
    return record, sim.applied


class ScriptedPeer:
    """A link whose peer answers every step with the next command of a script (messages as pymavlink
    parsed them, each held for its duration) and then hangs up. What the simulator sends is encoded
    by pymavlink (which raises on any field it cannot pack) and dropped."""

    peer_label = "scripted"

    def __init__(self, script) -> None:
        self.mav = transport.new_codec(self, 1, 1)
        self.bytes = 0
        # an autopilot's HEARTBEAT first: the simulator steps only once it has heard one
        (heartbeat,) = parse(mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3).pack(mavlink2.MAVLink(None)))
        self._script = iter([(heartbeat, 1), *script])
        self._msg, self._left = None, 0

    def write(self, buf) -> None:
        self.bytes += len(buf)

    def flush(self) -> None:
        pass

    def recv(self, timeout: float = 0.0):
        while self._left == 0:
            try:
                self._msg, self._left = next(self._script)
            except StopIteration:
                raise transport.PeerClosed("script done") from None
        self._left -= 1
        return self._msg


def actuator(controls, armed: bool):
    fields = wire.actuator_controls_fields(np.asarray(controls, np.float64), 0, armed, True)
    (msg,) = parse(mavlink2.MAVLink_hil_actuator_controls_message(**fields).pack(mavlink2.MAVLink(None)))
    return msg


# --- properties ------------------------------------------------------------------------------
@settings(PROPERTY, max_examples=200)
@given(byte_stream(NODE_MESSAGES))
def test_node_survives_any_bytes_and_hostile_messages_and_sends_only_safe_commands(data):
    log, sent, telemetry = fly_against(data)
    assert_node_output_safe(log, sent, telemetry)
    event(f"steps flown on a valid state: {'none' if not log.steps else 'some'}")  # --hypothesis-show-statistics
    armed = [m for m in sent if m.get_type() == "HIL_ACTUATOR_CONTROLS" and m.mode & wire.ARMED]
    event(f"steps answered: {'none' if not armed else 'some'}")
    event(f"states dropped: {'yes' if any(k.startswith('state_') for k in log.dropped) else 'no'}")


@settings(PROPERTY, max_examples=200)
@given(byte_stream(SIM_MESSAGES), st.booleans())
def test_simulator_survives_any_bytes_and_hostile_messages_and_applies_only_safe_commands(data, lockstep):
    record, applied = serve_bytes(data, lockstep)
    assert record.end_reason == "peer_closed"
    event(f"steps: {'none' if not record.steps else 'some'}, commands dropped: {bool(record.dropped)}")
    for cmd in applied:
        assert cmd.shape == (4,) and np.all(np.isfinite(cmd)) and np.all((cmd >= 0.0) & (cmd <= 1.0)), cmd
    assert np.all(np.isfinite(record.final_state))


STEPS_PER_RUN = 25_000
_unit = st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0))
_segment = st.tuples(st.lists(_unit, min_size=4, max_size=4), st.booleans(), st.integers(1, STEPS_PER_RUN))
_start = st.tuples(
    st.lists(st.one_of(st.floats(-10, 10), st.sampled_from([-1e6, 1e6, -2e4, 4e4])), min_size=3, max_size=3),
    st.lists(st.floats(-500, 500), min_size=3, max_size=3),
    st.lists(st.floats(-4, 4), min_size=3, max_size=3),
    st.lists(st.floats(-200, 200), min_size=3, max_size=3),
)


@settings(PROPERTY, max_examples=4)
@given(st.lists(_segment, min_size=1, max_size=12), _start)
def test_any_in_range_command_sequence_keeps_the_simulation_finite_and_encodable(segments, start):
    """4 runs × 25,000 steps (100,000 in all; 250 s simulated each) of held in-range commands,
    armed or not, from start states as far and fast as a long flight reaches: the plant's state
    stays finite and pymavlink packs every message of every step."""
    script, total = [], 0
    for controls, armed, steps in segments:
        steps = min(steps, STEPS_PER_RUN - total)
        if steps > 0:
            script.append((actuator(controls, armed), steps))
            total += steps
    if total < STEPS_PER_RUN:
        script.append((actuator([1.0] * 4, True), STEPS_PER_RUN - total))
    sim = Simulator(SimConfig(initial_state=tuple(float(v) for part in start for v in part)))
    link = ScriptedPeer(script)
    record = sim._run_episode(link, 0)
    assert record.steps == STEPS_PER_RUN and record.end_reason == "peer_closed"
    assert np.all(np.isfinite(record.final_state)), record.final_state
    assert sum(record.dropped.values()) == 0 and link.bytes > 0


# --- one regression test per attack that worked -----------------------------------------------
def _step_bytes(codec, t, state_fields):
    codec.hil_state_quaternion_send(**state_fields)
    z3 = np.zeros(3)
    codec.hil_sensor_send(**wire.hil_sensor_fields(t, z3, np.array([0.0, 0.0, 9.81]), z3, 955.0, 490.0))


def test_node_drops_states_that_cannot_be_states_and_answers_their_steps_once_with_hover():
    """A simulator sends a NaN quaternion (with ground-station telemetry on: a GLOBAL_POSITION_INT
    built from it), a zero quaternion and one of norm 2 between good steps. Each is dropped and
    counted by reason, its step answered exactly once with equal hover thrust, no telemetry comes
    from it, and the episode summary shows the drops."""
    sink = bytearray()

    class Out:
        def write(self, buf):
            sink.extend(buf)

    codec = transport.new_codec(Out(), 1, 1)
    good = wire.hil_state_quaternion_fields(HOVER_STATE, HOME, 0)
    quats = [[math.nan, 0.0, 0.0, 0.0], None, [0.0, 0.0, 0.0, 0.0], None, [2.0, 0.0, 0.0, 0.0], None]
    for t, q in zip(TIMES, quats, strict=True):
        fields = {**good, "time_usec": t}
        if q is not None:
            fields["attitude_quaternion"] = q
        _step_bytes(codec, t, fields)
    log, sent, telemetry = fly_against(bytes(sink))
    assert_node_output_safe(log, sent, telemetry)
    assert log.dropped["state_non_finite"] == 1 and log.dropped["state_quaternion_not_unit"] == 2
    answers = {m.time_usec: m for m in sent if m.get_type() == "HIL_ACTUATOR_CONTROLS" and m.mode & wire.ARMED}
    assert sorted(answers) == TIMES  # every step answered, once
    for t in (TIMES[0], TIMES[2], TIMES[4]):
        np.testing.assert_allclose(answers[t].controls[:4], [HOVER_CMD] * 4, rtol=1e-6)
    assert log.steps == 5  # the first step, flown blind before any valid state, has nothing to log against
    summary = episode_summary(log, 0.01)
    assert summary["dropped"]["state_non_finite"] == 1 and summary["dropped"]["state_quaternion_not_unit"] == 2


def test_long_climbs_and_falls_stay_within_the_wire_and_the_atmosphere():
    """Full thrust for 8,800 steps climbs past 43.8 km, where the troposphere formula's base turns
    negative (a complex pressure); free fall from 2 m passes −2,147 km after 662 s (66,176 steps),
    an altitude whose millimetres no int32 holds. Both must stay finite and encodable."""
    climb = [(actuator([1.0] * 4, True), 8_800)]
    sim = Simulator(SimConfig(initial_state=tuple(HOVER_STATE)))
    record = sim._run_episode(ScriptedPeer(climb), 0)
    assert record.steps == 8_800 and HOME.alt_m + record.final_state[2] > sensors.ISA_T0_K / sensors.ISA_LAPSE_K_PER_M
    t = 660.0  # the state after 66,000 steps of free fall, then 1,000 more steps of it
    g = VEHICLE.gravity
    fallen = (0.0, 0.0, 2.0 - 0.5 * g * t * t, 0.0, 0.0, -g * t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    sim = Simulator(SimConfig(initial_state=fallen))
    record = sim._run_episode(ScriptedPeer([(actuator([0.0] * 4, False), 1_000)]), 0)
    assert record.steps == 1_000 and np.all(np.isfinite(record.final_state))
    assert sensors.isa_pressure_hpa(1e6) == sensors.isa_pressure_hpa(sensors.ISA_TROPOPAUSE_M)
    f = wire.hil_state_quaternion_fields(np.array(record.final_state), HOME, 0)
    assert f["alt"] == -(2**31) and f["vz"] == 2**15 - 1  # saturated at int32 / int16


def test_bad_commands_do_not_keep_the_last_good_one_alive_in_realtime():
    """Realtime: one climbing command, then a stream of NaN and out-of-range commands every step.
    They are dropped, and they must not feed the ESC timeout: the motors are cut 100 ms after the
    last valid command and the vehicle falls, instead of climbing on for ever."""
    cfg = SimConfig(
        listen="tcp:127.0.0.1:0",
        episodes=1,
        initial_state=tuple(HOVER_STATE),
        lockstep=False,
        esc_timeout_s=0.1,
        max_steps=60,
        lockstep_timeout_s=2.0,
    )
    sim = Simulator(cfg)
    port = sim.bind().port
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("stats", sim.serve()), daemon=True)
    thread.start()
    link = transport.connect(f"tcp:127.0.0.1:{port}", 255, 190, 5.0)
    link.mav.heartbeat_send(2, 12, 0, 0, 3)  # the simulator steps only once it has heard one
    link.flush()
    zacc, sent_good = {}, False
    try:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            m = link.recv(0.5)
            if m is None or m.get_type() != "HIL_SENSOR":
                continue
            n = (m.time_usec - TIME_ORIGIN_US) // STEP_US
            zacc[n] = m.zacc
            bad = [0.9, math.nan, 0.9, 0.9] if n % 2 else [0.9, 1.5, 0.9, -0.5]
            link.mav.hil_actuator_controls_send(0, ([0.9] * 4 if not sent_good else bad) + [0.0] * 12, 128, 0)
            link.flush()
            sent_good = True
            if n >= cfg.max_steps:
                break
    finally:
        link.close()
        thread.join(5.0)
        sim.close()
    stats = result["stats"]
    (rec,) = stats.records
    assert rec.dropped.get("non_finite_control", 0) + rec.dropped.get("out_of_range_control", 0) > 30
    assert rec.esc_timeouts == 1 and 0.1 <= rec.esc_cut_silence_s < 0.2
    assert all(abs(zacc[n]) < 1e-6 for n in range(30, cfg.max_steps + 1))  # motors cut: free fall
    assert rec.final_state[5] < 0.0  # and it falls, not climbs


def test_bad_commands_cannot_hold_the_last_good_one_in_lockstep_either():
    """Lockstep: the same stream. Each bad command still answers its step (the peer waits for the
    next one), but after esc_timeout_s of simulated time without a valid command the motors cut."""
    bad = mavlink2.MAVLink_hil_actuator_controls_message(0, [0.9, math.nan, 0.9, 0.9] + [0.0] * 12, 128, 1)
    (bad,) = parse(bad.pack(mavlink2.MAVLink(None)))
    sim = Watched(SimConfig(initial_state=tuple(HOVER_STATE), esc_timeout_s=0.1))
    record = sim._run_episode(ScriptedPeer([(actuator([0.9] * 4, True), 1), (bad, 50)]), 0)
    assert record.steps == 51 and record.dropped == {"non_finite_control": 50}
    assert record.esc_timeouts == 1 and record.esc_cut_silence_s == pytest.approx(0.11)
    held = [float(c[0]) for c in sim.applied]
    assert held[:11] == [pytest.approx(0.9, rel=1e-6)] * 11 and held[11:] == [0.0] * 40


ROT = HOVER_LAYOUT.slices()["rot"]


@pytest.mark.parametrize(
    "rot",
    [
        np.full(9, 0.5),  # every entry in [−1, 1], no rotation
        np.diag([-1.0, 1.0, 1.0]).reshape(-1),  # orthonormal, determinant −1: a mirror image
        0.9 * np.eye(3).reshape(-1),  # orthogonal, not unit
        np.array([1.0, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),  # a shear
    ],
    ids=["all_0.5", "reflection", "scaled", "shear"],
)
def test_safety_monitor_refuses_an_attitude_that_is_no_rotation(rot):
    """An observation whose attitude block is no rotation, with every entry within [−1, 1] and the
    vehicle upright, never reaches the network: the step is flown blind at hover and counted."""
    obs = build_observation(HOVER_STATE[None], np.array([0.0, 0.0, 2.0]))[0].astype(np.float32)
    monitor = SafetyMonitor(policy())
    assert monitor.source == "policy" and np.all(np.isfinite(monitor.act(obs)))  # a real rotation flies
    obs[ROT] = rot
    cmd = monitor.act(obs)
    np.testing.assert_allclose(cmd, [HOVER_CMD] * 4, rtol=1e-6)
    assert monitor.events["obs_not_rotation"] == 1 and monitor.events["blind_steps"] == 1
    assert monitor.source == "fallback"


def test_plant_keeps_a_tumbling_vehicle_inside_the_model():
    """Opposite corners at full thrust spin the vehicle up without bound; the plant saturates the
    body rates at the wire's limit and keeps roll and pitch canonical."""
    v = SimConfig().vehicle_params
    plant = Plant(v, 0.01)
    plant.reset(HOVER_STATE)
    for _ in range(2_000):
        plant.step(np.array([1.0, 0.0, 1.0, 0.3]))
    s = plant.state
    assert np.all(np.isfinite(s)) and np.all(np.abs(s[9:12]) <= wire.MAX_BODY_RATE)
    assert abs(s[6]) <= math.pi and abs(s[7]) <= math.pi / 2 and plant.rate_limited_steps > 0
