"""Oracle tests of what `link.wire` accepts as a state and how it reads it, against hand values: the
attitude quaternion normalised (within 1 ± 1 %), body rates within ±70 rad/s, latitude within ±90°
and longitude within ±180° (degE7), ODOMETRY position and velocity within what HIL_STATE_QUATERNION's
integer fields can carry; each refusal a BadState whose `reason` is what the node counts drops by,
and whose one-line message names the message type and the value. Also the ODOMETRY covariance layout
(MAVLink: 21 floats, the upper-right triangle of a 6×6 matrix row by row, NaN first when unknown)
and the armed/lockstep bits of HIL_ACTUATOR_CONTROLS (mode bit 128, flags bit 1).
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from quadpilot.link import wire

HOME = wire.Home()
H = math.sqrt(0.5)


def hil_state(**changes) -> SimpleNamespace:
    """A valid HIL_STATE_QUATERNION (level, at home, at rest) with some fields replaced."""
    fields = wire.hil_state_quaternion_fields(np.zeros(12), HOME, 0)
    fields.update(changes)
    return SimpleNamespace(**fields)


def odometry(**changes) -> SimpleNamespace:
    fields = wire.odometry_fields(np.zeros(12), 0)
    fields.update(changes)
    return SimpleNamespace(**fields)


def refusal(read, msg) -> wire.BadState:
    with pytest.raises(wire.BadState) as info:
        read(msg)
    return info.value


def read_hil(msg):
    return wire.state_from_hil_state_quaternion(msg, HOME)


# --- the attitude quaternion --------------------------------------------------------------------


@pytest.mark.parametrize("read, make", [(read_hil, hil_state), (wire.state_from_odometry, odometry)])
def test_a_quaternion_within_one_percent_of_unit_length_is_normalised(read, make):
    """(w, x, y, z) and 1.005·(w, x, y, z) are the same attitude: roll 0.3 about north-east-down's
    north axis, read back as the same ENU/FLU Euler angles; and so for an attitude with every
    component non-zero (ENU/FLU roll 0.2, pitch −0.3, yaw 1.0, as the sender writes it)."""
    field = "attitude_quaternion" if make is hil_state else "q"
    q = np.array([math.cos(0.15), math.sin(0.15), 0.0, 0.0])
    unit = read(make(**{field: list(q)}))
    scaled = read(make(**{field: list(1.005 * q)}))
    np.testing.assert_allclose(scaled[6:9], unit[6:9], rtol=0, atol=1e-12)
    assert float(unit[6]) == pytest.approx(0.3, abs=1e-12)
    q = np.array(wire.ned_frd_quaternion(0.2, -0.3, 1.0))
    assert np.all(np.abs(q) > 0.05)
    for scale in (1.0, 0.995, 1.005):
        state = read(make(**{field: list(scale * q)}))
        np.testing.assert_allclose(state[6:9], [0.2, -0.3, 1.0], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "q, reason",
    [
        ([math.nan, 0.0, 0.0, 0.0], "non_finite"),
        ([1.0, math.inf, 0.0, 0.0], "non_finite"),
        ([0.0, 0.0, 0.0, 0.0], "quaternion_not_unit"),
        ([1.02, 0.0, 0.0, 0.0], "quaternion_not_unit"),
        ([0.5, 0.5, 0.0, 0.0], "quaternion_not_unit"),  # norm 0.707
    ],
)
def test_a_quaternion_that_is_no_attitude_is_refused_with_its_reason(q, reason):
    err = refusal(read_hil, hil_state(attitude_quaternion=q))
    assert err.reason == reason
    assert str(err).startswith("HIL_STATE_QUATERNION: ")
    err = refusal(wire.state_from_odometry, odometry(q=q))
    assert err.reason == reason
    assert str(err).startswith("ODOMETRY: ")


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_pitch_of_ninety_degrees_survives_rounding_beyond_one(sign):
    """The attitude (√½, 0, ±√½, 0): nose straight down or up. After normalisation the matrix entry
    2·(x·z − w·y) is ∓1.0000000000000002; the pitch is ∓90°, not a math domain error."""
    state = read_hil(hil_state(attitude_quaternion=[H, 0.0, sign * H, 0.0]))
    assert float(state[7]) == -sign * math.pi / 2


# --- body rates ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "read, make, name",
    [(read_hil, hil_state, "HIL_STATE_QUATERNION"), (wire.state_from_odometry, odometry, "ODOMETRY")],
)
@pytest.mark.parametrize("axis", ["rollspeed", "pitchspeed", "yawspeed"])
def test_each_body_rate_is_bounded_by_seventy_rad_per_second(read, make, name, axis):
    for v in (70.0, -70.0):  # the bound itself is a rate a state may carry
        read(make(**{axis: v}))
    err = refusal(read, make(**{axis: 70.5}))
    assert err.reason == "out_of_range"
    assert str(err) == f"{name}: body rate 70.5 rad/s, expected within ±70"
    err = refusal(read, make(**{axis: -71.0}))
    assert err.reason == "out_of_range"
    err = refusal(read, make(**{axis: math.nan}))
    assert err.reason == "non_finite"
    assert str(err).startswith(f"{name}: non-finite body rate ")


# --- latitude and longitude ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "lat, lon, ok",
    [
        (900_000_000, 0, True),  # the poles and the antimeridian are on the globe
        (-900_000_000, 0, True),
        (0, 1_800_000_000, True),
        (0, -1_800_000_000, True),
        (900_000_001, 0, False),
        (-900_000_001, 0, False),
        (0, 1_800_000_001, False),
        (0, -1_800_000_001, False),
        (473_977_420, 1_800_000_001, False),  # a valid latitude does not excuse the longitude
        (900_000_001, 85_455_940, False),
    ],
)
def test_latitude_and_longitude_must_be_on_the_globe(lat, lon, ok):
    msg = hil_state(lat=lat, lon=lon)
    if ok:
        state = read_hil(msg)
        assert float(state[1]) == pytest.approx((lat * 1e-7 - HOME.lat_deg) * HOME.metres_per_deg_lat, rel=1e-12)
    else:
        err = refusal(read_hil, msg)
        assert err.reason == "out_of_range"
        assert str(err) == f"HIL_STATE_QUATERNION: lat/lon {lat}/{lon} degE7 is off the globe"


# --- ODOMETRY -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "field, bound, unit",
    [
        ("x", wire.MAX_ESTIMATE_DISTANCE, "m"),
        ("z", wire.MAX_ESTIMATE_DISTANCE, "m"),
        ("vy", wire.MAX_ESTIMATE_SPEED, "m/s"),
    ],
)
def test_odometry_position_and_velocity_are_bounded(field, bound, unit):
    """Bounds: 2 147 483.647 m (int32 millimetres) and 327.67 m/s (int16 cm/s), inclusive."""
    for v in (bound, -bound):
        wire.state_from_odometry(odometry(**{field: v}))
    err = refusal(wire.state_from_odometry, odometry(**{field: 2 * bound}))
    assert err.reason == "out_of_range"
    assert str(err) == f"ODOMETRY: {2 * bound:.6g} {unit}, expected within ±{bound:g}"
    err = refusal(wire.state_from_odometry, odometry(**{field: -math.inf}))
    assert err.reason == "non_finite"
    assert str(err).startswith("ODOMETRY: non-finite value in [")


def test_odometry_in_other_frames_is_refused_with_reason_frame():
    err = refusal(wire.state_from_odometry, odometry(frame_id=wire.ODOMETRY_FRAME + 1))
    assert err.reason == "frame"
    assert str(err).startswith("ODOMETRY frames 2/12, expected 1 (LOCAL_NED) / 12 (BODY_FRD)")


def test_odometry_covariance_is_the_upper_triangle_row_by_row():
    """Row-major upper-right triangle of 6×6: the diagonal sits at 0, 6, 11, 15, 18, 20; everything
    else 0. Unknown: NaN first, the rest 0. Six variances, no more, no fewer."""
    f = wire.odometry_fields(np.zeros(12), 0, pose_variance=[1, 2, 3, 4, 5, 6])
    expected = [0.0] * 21
    for i, v in zip((0, 6, 11, 15, 18, 20), (1, 2, 3, 4, 5, 6), strict=True):
        expected[i] = float(v)
    assert f["pose_covariance"] == expected
    unknown = f["velocity_covariance"]
    assert len(unknown) == 21 and math.isnan(unknown[0]) and unknown[1:] == [0.0] * 20
    with pytest.raises(ValueError):
        wire.odometry_fields(np.zeros(12), 0, pose_variance=[1, 2, 3, 4, 5])


# --- HIL_ACTUATOR_CONTROLS ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "mode, flags, armed, lockstep",
    [
        (0, 0, False, False),
        (128, 0, True, False),
        (0, 1, False, True),
        (64 | 16, 2, False, False),
        (255, 3, True, True),
    ],
)
def test_armed_and_lockstep_are_single_bits(mode, flags, armed, lockstep):
    """MAV_MODE_FLAG_SAFETY_ARMED is bit 128 of mode, HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP bit 1 of
    flags; other bits say nothing about either."""
    msg = SimpleNamespace(controls=[0.25, 0.5, 0.75, 1.0] + [0.0] * 12, mode=mode, flags=flags)
    motors, is_armed, is_lockstep = wire.motors_from_actuator_controls(msg)
    np.testing.assert_array_equal(motors, [0.25, 0.5, 0.75, 1.0])
    assert (is_armed, is_lockstep) == (armed, lockstep)
