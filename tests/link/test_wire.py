"""The wire contract: ENU/FLU inside, NED/FRD and MAVLink's integer units outside, round trips
with known states, through pymavlink's own encoder and decoder."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from quadpilot.core.frames import euler_to_rotmat, rotmat_to_euler
from quadpilot.link import wire

HOME = wire.Home()


def through_the_wire(msg_cls, fields):
    """Encode with pymavlink, decode the bytes back: what the peer really receives."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    buf = msg_cls(**fields).pack(mav)
    (decoded,) = mavlink.MAVLink(None).parse_buffer(buf)
    return decoded


def test_frames_swap_axes_as_the_spec_says():
    # north-east-down: east 1 m and up 2 m is (north 0, east 1, down −2)
    np.testing.assert_array_equal(wire.enu_to_ned([1.0, 0.0, 2.0]), [0.0, 1.0, -2.0])
    # forward-right-down: a left-pointing body vector is −y in FRD, up is −z
    np.testing.assert_array_equal(wire.flu_to_frd([0.0, 1.0, 1.0]), [0.0, -1.0, -1.0])
    v = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_array_equal(wire.ned_to_enu(wire.enu_to_ned(v)), v)


def test_level_attitudes_map_to_the_expected_ned_quaternions():
    # level, nose east (ENU yaw 0) is NED yaw +90°: q = (cos 45°, 0, 0, sin 45°)
    q = wire.rotmat_to_quaternion(wire.rotmat_enu_flu_to_ned_frd(euler_to_rotmat(0.0, 0.0, 0.0)))
    np.testing.assert_allclose(q, [math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)], atol=1e-12)
    # level, nose north (ENU yaw 90°) is the NED identity
    q = wire.rotmat_to_quaternion(wire.rotmat_enu_flu_to_ned_frd(euler_to_rotmat(0.0, 0.0, math.pi / 2)))
    np.testing.assert_allclose(q, [1, 0, 0, 0], atol=1e-12)
    # right wing down in FLU (positive roll about forward) is right wing down in FRD too: NED roll +
    q = wire.rotmat_to_quaternion(wire.rotmat_enu_flu_to_ned_frd(euler_to_rotmat(0.3, 0.0, math.pi / 2)))
    np.testing.assert_allclose(q, [math.cos(0.15), math.sin(0.15), 0, 0], atol=1e-12)


def test_quaternion_round_trip_covers_every_branch():
    rng = np.random.default_rng(1)
    for _ in range(200):
        r = euler_to_rotmat(*rng.uniform([-math.pi, -1.5, -math.pi], [math.pi, 1.5, math.pi]))
        np.testing.assert_allclose(wire.quaternion_to_rotmat(wire.rotmat_to_quaternion(r)), r, atol=1e-12)
    for r in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):  # 180° turns
        np.testing.assert_allclose(wire.quaternion_to_rotmat(wire.rotmat_to_quaternion(r)), r, atol=1e-12)


def test_geodetic_resolution_and_round_trip():
    de, dn, du = HOME.position_quantum_m
    assert dn == pytest.approx(0.01112, rel=1e-3) and de == pytest.approx(dn * math.cos(math.radians(47.397742)))
    assert du == 1e-3
    rng = np.random.default_rng(2)
    for p in rng.uniform(-50, 50, (100, 3)):
        back = wire.geodetic_to_local(*wire.local_to_geodetic(p, HOME), HOME)
        assert np.all(np.abs(back - p) <= np.array(HOME.position_quantum_m) / 2 + 1e-9)
    lat, lon, alt = wire.local_to_geodetic([0.0, 0.0, 2.0], HOME)
    assert (lat, lon, alt) == (473977420, 85455940, 490000)


def test_hil_state_quaternion_round_trip_through_pymavlink():
    rng = np.random.default_rng(3)
    for _ in range(50):
        s = np.concatenate(
            [
                rng.uniform(-20, 20, 3),
                rng.uniform(-5, 5, 3),
                rng.uniform([-1.0, -1.0, -math.pi], [1.0, 1.0, math.pi]),
                rng.uniform(-5, 5, 3),
            ]
        )
        msg = through_the_wire(
            mavlink.MAVLink_hil_state_quaternion_message, wire.hil_state_quaternion_fields(s, HOME, 1)
        )
        back = wire.state_from_hil_state_quaternion(msg, HOME)
        assert np.all(np.abs(back[0:3] - s[0:3]) <= np.array(HOME.position_quantum_m) / 2 + 1e-9)
        assert np.all(np.abs(back[3:6] - s[3:6]) <= 0.005 + 1e-9)  # cm/s integers
        np.testing.assert_allclose(euler_to_rotmat(*back[6:9]), euler_to_rotmat(*s[6:9]), atol=1e-6)  # float32
        np.testing.assert_allclose(back[9:12], s[9:12], rtol=1e-6, atol=1e-6)


def test_vertical_velocity_and_body_rates_keep_their_physical_meaning():
    s = np.zeros(12)
    s[5] = 1.0  # climbing at 1 m/s
    s[8] = math.pi / 2  # nose north
    s[11] = 0.5  # yawing left (counter-clockwise seen from above), FLU +r
    f = wire.hil_state_quaternion_fields(s, HOME, 0)
    assert f["vz"] == -100  # NED: climbing is negative down-velocity
    assert f["yawspeed"] == pytest.approx(-0.5)  # FRD: counter-clockwise from above is negative yaw rate


def test_hil_sensor_gyro_round_trip():
    gyro = np.array([0.1, -0.2, 0.3])
    fields = wire.hil_sensor_fields(7, gyro, np.array([0, 0, 9.81]), np.array([0.2, 0, 0.4]), 1013.25, 0.0)
    msg = through_the_wire(mavlink.MAVLink_hil_sensor_message, fields)
    np.testing.assert_allclose(wire.gyro_from_hil_sensor(msg), gyro, rtol=1e-6)
    assert msg.zacc == pytest.approx(-9.81, rel=1e-6)  # FRD: the specific force at rest points up, −z


def test_actuator_controls_round_trip_and_refusals():
    fields = wire.actuator_controls_fields(np.array([0.1, 0.2, 0.3, 1.4]), 99, armed=True, lockstep=True)
    msg = through_the_wire(mavlink.MAVLink_hil_actuator_controls_message, fields)
    motors, armed, lockstep = wire.motors_from_actuator_controls(msg)
    np.testing.assert_allclose(motors, [0.1, 0.2, 0.3, 1.0], rtol=1e-6)  # clamped to [0, 1]
    assert armed and lockstep and msg.mode == 128 and msg.flags == 1
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(wire.NonFiniteCommand, match="non-finite"):
            wire.actuator_controls_fields(np.array([0.5, bad, 0.5, 0.5]), 0, True, True)
    with pytest.raises(ValueError, match="expected 4 motor commands"):
        wire.actuator_controls_fields(np.zeros(3), 0, True, True)


def test_hil_gps_fields_encode():
    s = np.zeros(12)
    s[3] = 1.0  # east 1 m/s
    msg = through_the_wire(mavlink.MAVLink_hil_gps_message, wire.hil_gps_fields(s, HOME, 5))
    assert (msg.vn, msg.ve, msg.vd, msg.vel, msg.cog, msg.fix_type) == (0, 100, 0, 100, 9000, 3)


def test_the_scalar_fast_paths_equal_the_matrix_compositions():
    """hil_state_quaternion_fields and state_from_hil_state_quaternion are written out in scalar
    arithmetic (they run every step); they must equal the documented matrix compositions."""
    from types import SimpleNamespace

    rng = np.random.default_rng(4)
    for _ in range(2000):
        s = np.zeros(12)
        s[0:6] = rng.uniform(-5, 5, 6)
        s[6], s[7], s[8] = rng.uniform(-3.1, 3.1), rng.uniform(-1.5, 1.5), rng.uniform(-3.14, 3.14)
        s[9:12] = rng.uniform(-4, 4, 3)
        f = wire.hil_state_quaternion_fields(s, HOME, 1)
        q_ref = wire.rotmat_to_quaternion(wire.rotmat_enu_flu_to_ned_frd(euler_to_rotmat(s[6], s[7], s[8])))
        np.testing.assert_allclose(f["attitude_quaternion"], q_ref, atol=1e-12)
        msg = SimpleNamespace(**f)
        back = wire.state_from_hil_state_quaternion(msg, HOME)
        r = wire.rotmat_ned_frd_to_enu_flu(wire.quaternion_to_rotmat(f["attitude_quaternion"]))
        np.testing.assert_allclose(back[6:9], rotmat_to_euler(r), atol=1e-12)
        np.testing.assert_allclose(back[0:3], wire.geodetic_to_local(f["lat"], f["lon"], f["alt"], HOME), atol=1e-12)
