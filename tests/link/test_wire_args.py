"""The messages of every simulation step go to pymavlink as one positional call (`wire.*_args`, the
fields in the message definition's order): the same frames as the keyword form, the same integer
saturation, and the same frame conversions as `link.frames`, to the bit."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from quadpilot.link import frames, wire
from quadpilot.link.transport import new_codec

HOME = wire.Home()
RNG = np.random.default_rng(11)


class _Bytes:
    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, buf) -> None:
        self.data += buf


def _frames(send, *args, **kwargs) -> bytes:
    out = _Bytes()
    mav = new_codec(out, 200, 200)
    getattr(mav, send)(*args, **kwargs)
    return bytes(out.data)


def _states(n=50):
    for _ in range(n):
        s = RNG.normal(0, 3, 12)
        s[6:9] = RNG.uniform(-3.2, 3.2, 3)
        yield s


CASES = [
    ("hil_state_quaternion", lambda s: (wire.hil_state_quaternion_args, (s, HOME, 1_000_000, s[9:12] * 9.0))),
    ("hil_sensor", lambda s: (wire.hil_sensor_args, (7, s[9:12], s[3:6], s[0:3] * 0.1, 1013.25, 488.0, 15.0))),
    ("hil_gps", lambda s: (wire.hil_gps_args, (s, HOME, 5))),
    ("hil_actuator_controls", lambda s: (wire.actuator_controls_args, (np.abs(s[0:4]) % 1.0, 99, True, True))),
]


@pytest.mark.parametrize("name, make", CASES, ids=[c[0] for c in CASES])
def test_positional_and_keyword_forms_are_the_same_frames(name, make):
    fields_of = {
        "hil_state_quaternion": wire.hil_state_quaternion_fields,
        "hil_sensor": wire.hil_sensor_fields,
        "hil_gps": wire.hil_gps_fields,
        "hil_actuator_controls": wire.actuator_controls_fields,
    }[name]
    cls = getattr(mavlink, f"MAVLink_{name}_message")
    for s in _states():
        args_of, args = make(s)
        positional, keywords = args_of(*args), fields_of(*args)
        assert list(keywords) == cls.fieldnames and list(keywords.values()) == positional
        assert _frames(f"{name}_send", *positional) == _frames(f"{name}_send", **keywords)


def test_integer_fields_saturate_by_position():
    """A fall from far above (altitude beyond int32 millimetres, speed beyond int16 cm/s) is still a
    message: the integers pinned at their type's limits, whichever form builds it."""
    s = np.zeros(12)
    s[2], s[5] = 3e6, -400.0  # 3,000 km up, falling at 400 m/s
    args = wire.hil_state_quaternion_args(s, HOME, 1, [0.0, 0.0, 1e6])
    names = mavlink.MAVLink_hil_state_quaternion_message.fieldnames
    got = dict(zip(names, args, strict=True))
    assert got["alt"] == 2**31 - 1 and got["vz"] == 2**15 - 1 and got["zacc"] == -(2**15)
    _frames("hil_state_quaternion_send", *args)  # packs (pymavlink raises struct.error on an overflow)
    gps = dict(zip(mavlink.MAVLink_hil_gps_message.fieldnames, wire.hil_gps_args(s, HOME, 1), strict=True))
    assert gps["alt"] == 2**31 - 1 and gps["vd"] == 2**15 - 1


def test_frame_conversions_are_link_frames_bit_for_bit():
    """FLU → FRD in HIL_SENSOR and ENU → NED in HIL_GPS are written out in scalar arithmetic (a
    multiplication by −1, as `frames.flu_to_frd`/`enu_to_ned` do it), signed zeros included."""
    nan = np.array([np.nan, -np.nan, np.nan])  # a NaN keeps its sign through ×(−1.0); −x would flip it
    edge = [np.array([0.0, -0.0, 0.0]), np.array([-0.0, 0.0, -0.0]), np.array([1e-310, -1e300, 3.5]), nan]
    for v in [*edge, *RNG.normal(0, 5, (200, 3))]:
        a = wire.hil_sensor_args(1, v, v * 2.0, v * 0.5, 1000.0, 0.0)
        for got, vec in ((a[4:7], v), (a[1:4], v * 2.0), (a[7:10], v * 0.5)):  # gyro, accel, mag
            assert np.array(got).tobytes() == frames.flu_to_frd(vec).tobytes()
        if not np.abs(v).max() <= 300.0:  # beyond int16 cm/s: saturated (test_integer_fields_saturate_by_position)
            continue
        s = np.zeros(12)
        s[3:6] = v
        g = dict(zip(mavlink.MAVLink_hil_gps_message.fieldnames, wire.hil_gps_args(s, HOME, 1), strict=True))
        vn, ve, vd = frames.enu_to_ned(v)
        assert (g["vn"], g["ve"], g["vd"]) == (round(vn * 100.0), round(ve * 100.0), round(vd * 100.0))
        assert g["cog"] == round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0) % 36000


def test_gyro_values_are_gyro_from_hil_sensor_bit_for_bit():
    for v in [np.array([0.0, -0.0, 0.0]), np.array([np.nan, -np.nan, np.nan]), *RNG.normal(0, 3, (200, 3))]:
        (msg,) = mavlink.MAVLink(None).parse_buffer(
            _frames("hil_sensor_send", *wire.hil_sensor_args(1, v, np.zeros(3), np.zeros(3), 1000.0, 0.0))
        )
        assert np.array(wire.gyro_values_from_hil_sensor(msg)).tobytes() == wire.gyro_from_hil_sensor(msg).tobytes()
